%% A step's states packed into one binary, as a body sends them to the
%% TVHT buckets. A binary of more than 64 bytes lives off the process heaps
%% and is passed by reference, so a bucket neither copies the states when it
%% receives them nor again at every garbage collection while it keeps them
%% (as tuples of boxed floats, copying them would be most of the buckets'
%% garbage collection work).
%% Floats are stored as IEEE doubles, bit for bit.
%%
%% Per substep: position, velocity, then (with rotation) orientation and
%% angular velocity, then (with CCD) the free displacement of the substep.
%% Packing also measures the box of the positions and the reach (the
%% largest move between two states), which the TVHT's narrowphase uses to
%% skip substeps at which two bodies are too far apart to touch.
-module(rw_states).
-include_lib("rw_physics/include/rw_physics.hrl").
-export([pack/4, packed/4, append/4, seal/3, for_probes/1, count/1, position/2, state/2, displacement/2, extents/1, reach/1,
         first_touch/6]).
-export_type([packed/0, extents/0]).

%% The box of the positions: {X0, Y0, Z0, X1, Y1, Z1}.
-type extents() :: rw_shape:box6().
-opaque packed() :: {RecordBytes :: pos_integer(), Rotation :: boolean(), Ccd :: boolean(), binary(),
                     extents() | {Scale :: float()}, Reach :: float() | undefined}.

%% Pack States (in order) with their free displacements (undefined
%% without CCD). One pass also measures the extents of the positions and
%% the reach (see reach/1). (A body alone packs its step's states so, at
%% write time; a group appends its members' states as it computes them,
%% append/4, and seals them, seal/3, which reads the positions back.)
-spec pack([#st{}], [rw_vec:vec()] | undefined, boolean(), boolean()) -> packed().
pack([#st{p = {X, Y, Z}} | _] = States, Disps, Rotation, Ccd) ->
    {Bin, Extents, Reach} = with_reach(fun(Reach0) -> pack(States, Disps, Rotation, <<>>, X, Y, Z, X, Y, Z, X, Y, Z,
                                                           Reach0) end),
    {record_size(Rotation, Ccd), Rotation, Ccd, Bin, Extents, Reach}.

%% Bytes per state.
record_size(Rotation, Ccd) -> 8 * (6 + case Rotation of true -> 7; false -> 0 end + case Ccd of true -> 3; false -> 0 end).

%% Measure(0.0), which measures the reach from zero; a move between
%% coordinates near the largest double overflows (far beyond what a scene
%% may hold): then Measure(undefined), no reach, and no skipping.
with_reach(Measure) ->
    try Measure(0.0)
    catch error:badarith -> Measure(undefined)
    end.

%% (a hot loop: the comparisons are written out rather than calls to
%% min/2 and max/2, and the binary is appended to in place)
pack([], _Disps, _Rot, Bin, _PX, _PY, _PZ, X0, Y0, Z0, X1, Y1, Z1, Reach) ->
    {Bin, {X0, Y0, Z0, X1, Y1, Z1}, Reach};
pack([#st{p = {X, Y, Z}} = St | Rest], Disps, Rot, Bin, PX, PY, PZ, X0, Y0, Z0, X1, Y1, Z1, Reach)
  when is_float(X), is_float(Y), is_float(Z), is_float(PX), is_float(PY), is_float(PZ), is_float(X0), is_float(Y0),
       is_float(Z0), is_float(X1), is_float(Y1), is_float(Z1) ->
    Step = case Reach of
               undefined -> undefined;
               _ -> abs(X - PX) + abs(Y - PY) + abs(Z - PZ)
           end,
    {Bin1, Disps1} = case Disps of
                         undefined -> {record(Bin, St, Rot), undefined};
                         [{DX, DY, DZ} | More] ->
                             {<<(record(Bin, St, Rot))/binary, DX:64/float, DY:64/float, DZ:64/float>>, More}
                     end,
    pack(Rest, Disps1, Rot, Bin1, X, Y, Z,
         if X < X0 -> X; true -> X0 end, if Y < Y0 -> Y; true -> Y0 end, if Z < Z0 -> Z; true -> Z0 end,
         if X > X1 -> X; true -> X1 end, if Y > Y1 -> Y; true -> Y1 end, if Z > Z1 -> Z; true -> Z1 end,
         if Reach =:= undefined -> undefined; Step > Reach -> Step; true -> Reach end).

%% States appended to Bin (append/4, without CCD) packed with the box of
%% their positions and their reach, measured as pack/4 measures them.
-spec packed(binary(), boolean(), extents(), float()) -> packed().
packed(Bin, Rotation, Extents, Reach) -> {record_size(Rotation, false), Rotation, false, Bin, Extents, Reach}.

%% One more state (with CCD, and its free displacement) at the end of Bin.
%% A step's states are appended as they are computed: the binary grows in
%% place, off the heap, so the states of a long step are never copied by
%% the garbage collector of the body that computes them.
-spec append(binary(), #st{}, rw_vec:vec() | undefined, boolean()) -> binary().
append(Bin, St, undefined, Rotation) -> record(Bin, St, Rotation);
append(Bin, St, {DX, DY, DZ}, Rotation) ->
    <<(record(Bin, St, Rotation))/binary, DX:64/float, DY:64/float, DZ:64/float>>.

%% The states appended to Bin (append/4), packed: one pass measures the
%% extents of the positions and the reach (see reach/1).
-spec seal(binary(), boolean(), boolean()) -> packed().
seal(<<X:64/float, Y:64/float, Z:64/float, _/binary>> = Bin, Rotation, Ccd) ->
    Size = record_size(Rotation, Ccd),
    %% (the C loop where it is loaded: rw_native)
    {Extents, Reach} =
        case rw_native:enabled() andalso rw_native:measure(Bin, Size) of
            {_, _} = Measured -> Measured;
            _ -> with_reach(fun(Reach0) -> measure(Size - 24, Bin, X, Y, Z, X, Y, Z, X, Y, Z, Reach0) end)
        end,
    {Size, Rotation, Ccd, Bin, Extents, Reach}.

%% pack/14's measurement over the positions read back from the binary
%% (a hot loop: the comparisons are written out rather than calls to
%% min/2 and max/2)
measure(Skip, Bin, PX, PY, PZ, X0, Y0, Z0, X1, Y1, Z1, Reach) ->
    case Bin of
        <<X:64/float, Y:64/float, Z:64/float, _:Skip/binary, Rest/binary>> ->
            Step = case Reach of
                       undefined -> undefined;
                       _ -> abs(X - PX) + abs(Y - PY) + abs(Z - PZ)
                   end,
            measure(Skip, Rest, X, Y, Z,
                    if X < X0 -> X; true -> X0 end, if Y < Y0 -> Y; true -> Y0 end, if Z < Z0 -> Z; true -> Z0 end,
                    if X > X1 -> X; true -> X1 end, if Y > Y1 -> Y; true -> Y1 end, if Z > Z1 -> Z; true -> Z1 end,
                    if Reach =:= undefined -> undefined; Step > Reach -> Step; true -> Reach end);
        <<>> ->
            {{X0, Y0, Z0, X1, Y1, Z1}, Reach}
    end.

record(Bin, #st{p = {PX, PY, PZ}, v = {VX, VY, VZ}}, false) ->
    <<Bin/binary, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float>>;
record(Bin, #st{p = {PX, PY, PZ}, v = {VX, VY, VZ}, q = {{QX, QY, QZ}, QW}, w = {WX, WY, WZ}}, true) ->
    <<Bin/binary, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float,
      QX:64/float, QY:64/float, QZ:64/float, QW:64/float, WX:64/float, WY:64/float, WZ:64/float>>.

%% The box of the packed positions (not of states for_probes/1 gave).
-spec extents(packed()) -> extents().
extents({_, _, _, _, {_, _, _, _, _, _} = Extents, _}) -> Extents.

%% The states as the TVHT's buckets keep them: their probes read the box
%% of the positions only for its largest coordinate (first_touch/6), so
%% that is all they get, one float for six (the buckets of tens of
%% thousands of bodies keep and collect a sixth less).
-spec for_probes(packed()) -> packed().
for_probes({Size, Rotation, Ccd, Bin, Extents, Reach}) -> {Size, Rotation, Ccd, Bin, {largest(Extents)}, Reach}.

largest({Scale}) -> Scale;
largest(Extents) -> scale(Extents).

%% An upper bound on how far the centre moves from one state to the next
%% (the largest |dx| + |dy| + |dz|, which is at least the distance), for
%% first_touch/6 to skip substeps at which two bodies cannot touch yet.
-spec reach(packed()) -> float() | undefined.
reach({_, _, _, _, _, Reach}) -> Reach.

-spec count(packed()) -> non_neg_integer().
count({Size, _, _, Bin, _, _}) -> byte_size(Bin) div Size.

%% Position at the I-th state (1-based).
-spec position(packed(), pos_integer()) -> rw_vec:vec().
position({Size, _, _, Bin, _, _}, I) ->
    Skip = (I - 1) * Size,
    <<_:Skip/binary, X:64/float, Y:64/float, Z:64/float, _/binary>> = Bin,
    {X, Y, Z}.

-spec state(packed(), pos_integer()) -> #st{}.
state({Size, Rotation, _, Bin, _, _}, I) ->
    Skip = (I - 1) * Size,
    case Rotation of
        false ->
            <<_:Skip/binary, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float,
              _/binary>> = Bin,
            #st{p = {PX, PY, PZ}, v = {VX, VY, VZ}};
        true ->
            <<_:Skip/binary, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float,
              QX:64/float, QY:64/float, QZ:64/float, QW:64/float, WX:64/float, WY:64/float, WZ:64/float,
              _/binary>> = Bin,
            #st{p = {PX, PY, PZ}, v = {VX, VY, VZ}, q = {{QX, QY, QZ}, QW}, w = {WX, WY, WZ}}
    end.

%% Free displacement over the I-th substep (CCD only), else undefined.
-spec displacement(packed(), pos_integer()) -> rw_vec:vec() | undefined.
displacement({_, _, false, _, _, _}, _I) -> undefined;
displacement({Size, _, true, Bin, _, _}, I) ->
    Skip = I * Size - 24,
    <<_:Skip/binary, X:64/float, Y:64/float, Z:64/float, _/binary>> = Bin,
    {X, Y, Z}.

%% The first offset K in 0..Left at which the positions IA + K of StsA and
%% IB + K of StsB are closer than Sum (the test the narrowphase makes:
%% distance squared below Sum squared), or none. With Reach the sum of
%% both reaches (reach/1): while the centres are D apart, for the next
%% (D - Sum - Margin) / Reach substeps they stay more than Sum + Margin
%% apart, and are not read. Margin is far above the rounding of D and of
%% the multiples of Reach, so no touch is ever skipped; the offset found is
%% the one a check of every substep finds.
%% (The scan is the C loop's, rw_native:first_touch/10, where it can take
%% it: the same operations.)
-spec first_touch(packed(), pos_integer(), packed(), pos_integer(), non_neg_integer(), float()) ->
          non_neg_integer() | none.
first_touch({_, _, _, _, _, ReachA} = StsA, IA, {_, _, _, _, _, ReachB} = StsB, IB, Left, Sum)
  when ReachA =:= undefined; ReachB =:= undefined ->
    scan(IA, IB, Left, StsA, StsB, Sum, 0.0, undefined);
first_touch(StsA, IA, StsB, IB, Left, Sum) ->
    Margin = 1.0e-9 * (Sum + max(largest(element(5, StsA)), largest(element(5, StsB)))),
    Reach = (reach(StsA) + reach(StsB)) * (1.0 + 1.0e-9),
    scan(IA, IB, Left, StsA, StsB, Sum, Margin, Reach).

scan(IA, IB, Left, {SizeA, _, _, BinA, _, _} = StsA, {SizeB, _, _, BinB, _, _} = StsB, Sum, Margin, Reach) ->
    case rw_native:enabled() andalso rw_native:first_touch(BinA, SizeA, IA, BinB, SizeB, IB, Left, Sum, Margin, Reach) of
        Found when is_integer(Found); Found =:= none -> Found;
        _ -> touch(IA, IB, Left, StsA, StsB, Sum, Sum * Sum, Margin, Reach, 0)
    end.

scale({X0, Y0, Z0, X1, Y1, Z1}) -> max(max(max(abs(X0), abs(Y0)), max(abs(Z0), abs(X1))), max(abs(Y1), abs(Z1))).

touch(IA, IB, Left, StsA, StsB, Sum, Sum2, Margin, Reach, K) ->
    {XA, YA, ZA} = position(StsA, IA),
    {XB, YB, ZB} = position(StsB, IB),
    DX = XB - XA, DY = YB - YA, DZ = ZB - ZA,
    D2 = DX * DX + DY * DY + DZ * DZ,
    if
        D2 < Sum2 -> K;
        Left =:= 0 -> none;
        true ->
            Gap = math:sqrt(D2) - Sum - Margin,
            %% substeps 1..Skip from here are certainly apart
            Skip = if
                       Reach =:= undefined -> 0;
                       Gap =< Reach -> 0;
                       Gap >= Left * Reach -> Left;
                       true -> trunc(Gap / Reach)
                   end,
            case Skip >= Left of
                true -> none;
                false -> touch(IA + Skip + 1, IB + Skip + 1, Left - Skip - 1, StsA, StsB, Sum, Sum2, Margin,
                               Reach, K + Skip + 1)
            end
    end.
