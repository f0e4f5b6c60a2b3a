%% Broadphase: the pairs of bodies close enough to be worth a full test.
%% Pure, two ways:
%%   sweep/2  sweep and prune along x. Items sorted by x, each tested
%%            against those after it up to where its window along x ends:
%%            spheres are cut by y and z, then tested by distance (contact
%%            groups, rw_regroup; an island's neighbour list, rw_island);
%%            spans are pairs of closed intervals that overlap (the accuracy
%%            bench's missed collisions, rw_accuracy).
%%   grid/3   a uniform grid of rw_hash cells: the pairs whose boxes (or
%%            swept spheres) share a cell (the reference engine,
%%            rw_reference; the scene validator's overlaps, rw_scene).
%% A sphere pair is found when its test passes and the second's centre is
%% closer than the first's reach along each axis: with a reach no smaller
%% than the test's distance, the pairs of a test of every pair.
-module(rw_broadphase).
-export([sweep/2, grid/3]).
-export_type([sphere/1, span/1, test/0]).

%% A sphere of the sweep: its centre X, Y, Z, radius R and reach. Partners
%% are sought closer than Reach along every axis; Key names it. X first, so
%% that the sweep's order is by x, then by key. Flat, so that the hot loop
%% keeps its coordinates in float registers.
-type sphere(K) :: {X :: float(), K, Y :: float(), Z :: float(), R :: float(), Reach :: float()}.
%% A closed interval along x, [Lo, Hi].
-type span(K) :: {Lo :: float(), K, Hi :: float()}.
%% What the sweep returns for spheres A and B (D their distance, Sum the
%% sum of their radii):
%%   {distance, F}  {{A, B}, D, Sum} where D is less than F x Sum
%%   {skin, Skin}   {A, B} where D^2 is less than (Sum + Skin)^2, without a
%%                  square root
%% and, for spans, the atom spans: {A, B} where they overlap.
-type test() :: {distance, float()} | {skin, float()} | spans.

%% The pairs that pass Test, each once with the lower key first. Keys are
%% unique. The order of the pairs is fixed by the items: the reverse of the
%% order in which the sweep finds them (by the first member's x, then by
%% the second's).
-spec sweep([sphere(K)], {distance, float()}) -> [{{K, K}, float(), float()}];
           ([sphere(K)], {skin, float()}) -> [{K, K}];
           ([span(K)], spans) -> [{K, K}].
sweep(Items, Test) -> scan(lists:sort(Items), Test, []).

scan([], _Test, Acc) -> Acc;
scan([{_Lo, K, Hi} | Rest], spans, Acc) ->
    scan(Rest, spans, overlapping(Rest, Hi, K, Acc));
scan([{X, K, Y, Z, R, Reach} | Rest], Test, Acc) ->
    scan(Rest, Test, near(Rest, X + Reach, Reach, Test, K, X, Y, Z, R, Acc)).

%% (the hot loop: the GVT process runs it for contact groups at every
%% regroup point, which every body waits for, and an island for its
%% neighbour list; most spheres within reach along x are far along y or z,
%% and two comparisons reject them before any distance is computed)
near([{XB, KB, YB, ZB, RB, _} | Rest], XMax, Reach, Test, KA, XA, YA, ZA, RA, Acc)
  when XB < XMax, is_float(XB), is_float(YB), is_float(ZB), is_float(XA), is_float(YA), is_float(ZA),
       is_float(Reach), is_float(RA), is_float(RB) ->
    DY = YB - YA,
    DZ = ZB - ZA,
    case DY >= Reach orelse -DY >= Reach orelse DZ >= Reach orelse -DZ >= Reach of
        true ->
            near(Rest, XMax, Reach, Test, KA, XA, YA, ZA, RA, Acc);
        false ->
            DX = XB - XA,
            %% (rw_vec:len2/1 of the difference, operation for operation)
            D2 = DX * DX + DY * DY + DZ * DZ,
            near(Rest, XMax, Reach, Test, KA, XA, YA, ZA, RA, test(Test, D2, KA, KB, RA, RB, Acc))
    end;
near(_, _XMax, _Reach, _Test, _KA, _XA, _YA, _ZA, _RA, Acc) -> Acc.

test({distance, F}, D2, KA, KB, RA, RB, Acc) when is_float(F), is_float(D2) ->
    Sum = RA + RB,
    Dist = math:sqrt(D2),
    case Dist < F * Sum of
        true -> [{{min(KA, KB), max(KA, KB)}, Dist, Sum} | Acc];
        false -> Acc
    end;
test({skin, Skin}, D2, KA, KB, RA, RB, Acc) when is_float(Skin), is_float(D2) ->
    S = RA + RB + Skin,
    case D2 < S * S of
        true -> [{min(KA, KB), max(KA, KB)} | Acc];
        false -> Acc
    end.

overlapping([{Lo, KB, _} | Rest], Hi, KA, Acc) when Lo =< Hi ->
    overlapping(Rest, Hi, KA, [{min(KA, KB), max(KA, KB)} | Acc]);
overlapping(_, _Hi, _KA, Acc) -> Acc.

%% Every pair of items 1..N whose extents (BoxOf(K) for item K: a box, or
%% a swept sphere) share a cell of the grid of side CellSize
%% (rw_hash:cells/2), once, as {A, B} with A < B. The order is fixed by the
%% extents: cell by cell in the order of the cells in a map, each pair
%% where it first appears. (Extents are asked for one at a time rather
%% than given as a list: the reference engine calls this at every substep,
%% and a list would be built and collected each time.)
-spec grid(non_neg_integer(), fun((pos_integer()) -> rw_hash:extent()), float()) -> [{pos_integer(), pos_integer()}].
grid(N, BoxOf, CellSize) ->
    {_, Pairs} = maps:fold(fun(_, [_], Acc) -> Acc;
                              (_, Ks, Acc) -> once([{A, B} || A <- Ks, B <- Ks, A < B], Acc)
                           end, {#{}, []}, cells(1, N, BoxOf, CellSize, #{})),
    lists:reverse(Pairs).

%% Cell => the items whose boxes touch it, the last first.
cells(K, N, _BoxOf, _CellSize, Cells) when K > N -> Cells;
cells(K, N, BoxOf, CellSize, Cells) -> cells(K + 1, N, BoxOf, CellSize, add(rw_hash:cells(BoxOf(K), CellSize), K, Cells)).

add([], _K, Cells) -> Cells;
add([C | Cs], K, Cells) ->
    case Cells of
        #{C := Ks} -> add(Cs, K, Cells#{C := [K | Ks]});
        _ -> add(Cs, K, Cells#{C => [K]})
    end.

%% The pairs not seen before, added to the list (newest first).
once([], Acc) -> Acc;
once([P | Rest], {Seen, Pairs} = Acc) ->
    case Seen of
        #{P := _} -> once(Rest, Acc);
        _ -> once(Rest, {Seen#{P => true}, [P | Pairs]})
    end.
