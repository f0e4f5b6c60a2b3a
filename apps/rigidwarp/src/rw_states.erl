%% A step's states packed into one binary, as a body sends them to the
%% TVHT buckets. A binary of more than 64 bytes lives off the process heaps
%% and is passed by reference, so a bucket neither copies the states when it
%% receives them nor again at every garbage collection while it keeps them
%% (as tuples of boxed floats they were most of the buckets' GC work).
%% Floats are stored as IEEE doubles, bit for bit.
%%
%% Per substep: position, velocity, then (with rotation) orientation and
%% angular velocity, then (with CCD) the free displacement of the substep.
-module(rw_states).
-include_lib("rw_physics/include/rw_physics.hrl").
-export([pack/4, count/1, position/2, state/2, displacement/2, reach/1, first_touch/8]).
-export_type([packed/0]).

-opaque packed() :: {RecordBytes :: pos_integer(), Rotation :: boolean(), Ccd :: boolean(), binary()}.

%% Pack States (in order) with their free displacements (undefined
%% without CCD).
-spec pack([#st{}], [rw_vec:vec()] | undefined, boolean(), boolean()) -> packed().
pack(States, Disps, Rotation, Ccd) ->
    Size = 8 * (6 + case Rotation of true -> 7; false -> 0 end + case Ccd of true -> 3; false -> 0 end),
    Bin = case Disps of
              undefined -> << <<(record(St, Rotation))/binary>> || St <- States >>;
              _ -> << <<(record(St, Rotation))/binary, X:64/float, Y:64/float, Z:64/float>>
                      || {St, {X, Y, Z}} <- lists:zip(States, Disps) >>
          end,
    {Size, Rotation, Ccd, Bin}.

record(#st{p = {PX, PY, PZ}, v = {VX, VY, VZ}}, false) ->
    <<PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float>>;
record(#st{p = {PX, PY, PZ}, v = {VX, VY, VZ}, q = {{QX, QY, QZ}, QW}, w = {WX, WY, WZ}}, true) ->
    <<PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float,
      QX:64/float, QY:64/float, QZ:64/float, QW:64/float, WX:64/float, WY:64/float, WZ:64/float>>.

-spec count(packed()) -> non_neg_integer().
count({Size, _, _, Bin}) -> byte_size(Bin) div Size.

%% Position at the I-th state (1-based).
-spec position(packed(), pos_integer()) -> rw_vec:vec().
position({Size, _, _, Bin}, I) ->
    Skip = (I - 1) * Size,
    <<_:Skip/binary, X:64/float, Y:64/float, Z:64/float, _/binary>> = Bin,
    {X, Y, Z}.

-spec state(packed(), pos_integer()) -> #st{}.
state({Size, Rotation, _, Bin}, I) ->
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
displacement({_, _, false, _}, _I) -> undefined;
displacement({Size, _, true, Bin}, I) ->
    Skip = I * Size - 24,
    <<_:Skip/binary, X:64/float, Y:64/float, Z:64/float, _/binary>> = Bin,
    {X, Y, Z}.

%% An upper bound on how far the centre moves from one state to the next
%% (the largest |dx| + |dy| + |dz|, which is at least the distance), for
%% first_touch/8 to skip substeps at which two bodies cannot touch yet.
-spec reach([#st{}]) -> float().
reach([#st{p = {X, Y, Z}} | Rest]) -> reach(Rest, X, Y, Z, 0.0).

reach([], _X, _Y, _Z, Max) -> Max;
reach([#st{p = {X, Y, Z}} | Rest], PX, PY, PZ, Max) ->
    Step = abs(X - PX) + abs(Y - PY) + abs(Z - PZ),
    reach(Rest, X, Y, Z, if Step > Max -> Step; true -> Max end).

%% The first offset K in 0..Left at which the positions IA + K of StsA and
%% IB + K of StsB are closer than Sum (the test the narrowphase makes:
%% distance squared below Sum squared), or none. Reach is ReachA + ReachB
%% (reach/1): while the centres are D apart, for the next
%% (D - Sum - Margin) / Reach substeps they stay more than Sum + Margin
%% apart, and are not read. Margin is far above the rounding of D and of
%% the multiples of Reach, so no touch is ever skipped; the offset found is
%% the one a check of every substep finds.
-spec first_touch(packed(), pos_integer(), packed(), pos_integer(), non_neg_integer(), float(), float(), float()) ->
          non_neg_integer() | none.
first_touch(StsA, IA, StsB, IB, Left, Sum, Margin, Reach) ->
    touch(IA, IB, Left, StsA, StsB, Sum, Sum * Sum, Margin, Reach * (1.0 + 1.0e-9), 0).

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
