%% Where a write to the TVHT goes (pure): an entity's step (each member's
%% packed states, one per substep from T0 on) becomes one write payload
%% per member, and for each cell a member's box touches during the step,
%% the first and last substep at which it does, grouped by bucket in bucket
%% order, the order in which the buckets are locked (Lemma 1).
-module(rw_tvht_plan).
-include("rigidwarp.hrl").
-export([write/7, write/8, for_bucket/2, first_contacts/2, delete/1, grid/1, on_grid/2, max_write_cells/0]).
-export_type([plan/0, where/0, cache/0]).

%% The most cells one member's write may cover (max_write_cells/0).
-define(MAX_WRITE_CELLS, 262144).

%% Per bucket index, ascending: the cells written and the spans in them.
-type plan() :: [{non_neg_integer(), [rw_hash:cell()], [rw_cells:span()]}].
%% Where a write went: per bucket index, its cells.
-type where() :: [{non_neg_integer(), [rw_hash:cell()]}].
%% A writer's last plan without its times, for write/8: each member's box
%% of cells, and per bucket its cells in order with the members in each,
%% ascending (the plan but its times).
-type cache() :: none | {[{non_neg_integer(), rw_hash:box()}],
                         #{non_neg_integer() => {[rw_hash:cell()], [{rw_hash:cell(), [non_neg_integer()]}]}}}.

%% The write of an entity's step: Writer's members Spheres (a tuple, in
%% member order) with their packed states Steps from T0 on, and its plan
%% over a pool of NBuckets buckets or a placement of buckets on several
%% nodes.
-spec write(term(), non_neg_integer(), tuple(), [rw_states:packed()], #model{}, {float(), pos_integer()},
            pos_integer() | rw_place:placement()) -> {rw_cells:write(), plan()}.
write(Writer, T0, Spheres, Steps, #model{ccd = Ccd}, {CellSize, Dt}, NBuckets) ->
    {Members, Write} = members(Writer, T0, Spheres, Steps, Ccd, grid(CellSize)),
    Plan = plan([{Idx, cell_spans(T0, Spans, CellSize, Dt)} || {{Idx, _, _, _, _, _}, Spans} <- Members], NBuckets),
    {Write, Plan}.

%% Each member's payload with what cell_spans/4 needs, and the write of
%% them all.
members(Writer, T0, Spheres, Steps, Ccd, Grid) ->
    Members = [member_write(Writer, element(K, Spheres), T0, Packed, Ccd, Grid)
               || {K, Packed} <- lists:zip(lists:seq(1, length(Steps)), Steps)],
    {Members, {Writer, T0, maps:from_list([{Idx, Payload} || {{Idx, _, _, _, _, _} = Payload, _} <- Members]),
               union([Bounds || {{_, _, _, _, _, Bounds}, _} <- Members])}}.

%% write/7 for a writer that writes again and again with its members in
%% much the same cells (bodies resting in a pile, a group in lock step with
%% a neighbour): when each member spanned the box of cells of its states
%% for the whole of the last write, and does so again, the plan is that
%% write's with the new times, the members whose boxes changed moved to
%% their new cells: only their cells are hashed to buckets. (In a pile of
%% hundreds, some member crosses a cell border at almost every write.) The
%% plan is write/7's, term for term; spanning a whole box for the whole
%% step covers every cell a member touches at every substep (a wider span
%% adds candidates to the buckets' tests, never contacts).
-spec write(term(), non_neg_integer(), tuple(), [rw_states:packed()], #model{}, {float(), pos_integer()},
            pos_integer() | rw_place:placement(), cache()) -> {rw_cells:write(), plan(), cache()}.
write(Writer, T0, Spheres, Steps, #model{ccd = false}, {CellSize, Dt}, NBuckets, Cache) ->
    [N | Counts] = [rw_states:count(Packed) || Packed <- Steps],
    {Members, Write} = members(Writer, T0, Spheres, Steps, false, grid(CellSize)),
    Shape = [{Idx, all_box(Extents, R, CellSize)} || {{Idx, _, _, _, _, _}, {_, Extents, R}} <- Members],
    Tb = T0 + (N - 1) * Dt,
    Even = lists:all(fun(C) -> C =:= N end, Counts),
    case Even andalso moved(Cache, Shape, Members, CellSize, NBuckets) of
        {ok, {_, Skeleton} = Cache1} ->
            {Write, [{B, Cells, [{C, T0, Tb, [{I, T0, Tb} || I <- Is]} || {C, Is} <- ByCell]}
                     || {B, {Cells, ByCell}} <- lists:sort(maps:to_list(Skeleton))], Cache1};
        _ ->
            MemberSpans = [{Idx, cell_spans(T0, Spans, CellSize, Dt)} || {{Idx, _, _, _, _, _}, Spans} <- Members],
            Plan = plan(MemberSpans, NBuckets),
            {Write, Plan, cache(Shape, MemberSpans, Plan, T0, Tb)}
    end;
write(Writer, T0, Spheres, Steps, M, CellDt, NBuckets, _Cache) ->
    {Write, Plan} = write(Writer, T0, Spheres, Steps, M, CellDt, NBuckets),
    {Write, Plan, none}.

%% The cells of every state of a step (without CCD): its extents padded by
%% the radius.
all_box({X0, Y0, Z0, X1, Y1, Z1}, R, C) -> rw_hash:box({{X0 - R, Y0 - R, Z0 - R}, {X1 + R, Y1 + R, Z1 + R}}, C).

%% A plan is kept for the next write when each member spanned the cells of
%% its box for the whole step (and only then do they stand for its box).
cache(Shape, MemberSpans, Plan, T0, Tb) ->
    Whole = lists:all(fun({{_, Box}, {_, Spans}}) ->
                              map_size(Spans) =:= rw_hash:box_size(Box) andalso
                                  lists:all(fun({Ta, Tz}) -> Ta =:= T0 andalso Tz =:= Tb end, maps:values(Spans))
                      end, lists:zip(Shape, MemberSpans)),
    case Whole of
        true -> {Shape, maps:from_list([{B, {Cells, [{C, [I || {I, _, _} <- Ms]} || {C, _, _, Ms} <- Spans]}}
                                        || {B, Cells, Spans} <- Plan])};
        false -> none
    end.

%% The last write's plan (but its times) with the members whose boxes
%% changed in their new cells, when the same members write again and each
%% spans its whole box again (as cell_spans/4 decides: each member that
%% kept its box did last time, but the decision depends on where its step
%% starts too); else fresh, also when fewer members kept their boxes than
%% changed them.
moved(none, _Shape, _Members, _CellSize, _NB) -> fresh;
moved({Old, Skeleton} = Cache, Shape, Members, CellSize, NB) ->
    case changed(Old, Shape, [], 0) of
        {Changed, Kept} when Kept >= length(Changed) ->
            case lists:all(fun({{_, {Packed, _, R}}, {_, All}}) -> whole(Packed, All, R, CellSize) end,
                           lists:zip(Members, Shape)) of
                true when Changed =:= [] -> {ok, Cache};
                true -> {ok, {Shape, move(Changed, NB, Skeleton)}};
                false -> fresh
            end;
        _ -> fresh
    end.

%% The members whose boxes changed, {Idx, Old, New}, and how many kept
%% theirs; different when the members are not the same.
changed([], [], Changed, Kept) -> {Changed, Kept};
changed([{I, Box} | Old], [{I, Box} | New], Changed, Kept) -> changed(Old, New, Changed, Kept + 1);
changed([{I, OldBox} | Old], [{I, NewBox} | New], Changed, Kept) ->
    changed(Old, New, [{I, OldBox, NewBox} | Changed], Kept);
changed(_, _, _, _) -> different.

%% Does cell_spans/4 span every cell of All, the box of all the states of
%% a step, for the whole step? (A box of at most two cells is at most
%% twice the first state's box.)
whole(Packed, All, R, C) ->
    AllSize = rw_hash:box_size(All),
    AllSize =< 2 orelse begin
                            Box = rw_hash:box(aabb(Packed, 1, R), C),
                            All =:= Box orelse AllSize =< 2 * rw_hash:box_size(Box)
                        end.

%% The skeleton with each changed member out of the cells of its old box
%% and into those of its new one; the buckets touched are rebuilt in order.
move(Changed, NB, Skeleton) ->
    Out = lists:foldl(fun({I, OldBox, _}, Acc) ->
                              edit_all(rw_hash:box_cells(OldBox), NB, fun(Is) -> lists:delete(I, Is) end, Skeleton, Acc)
                      end, #{}, Changed),
    In = lists:foldl(fun({I, _, NewBox}, Acc) ->
                             edit_all(rw_hash:box_cells(NewBox), NB, fun(Is) -> lists:merge([I], Is) end, Skeleton, Acc)
                     end, Out, Changed),
    maps:fold(fun(B, Cells, Skel) when map_size(Cells) =:= 0 -> maps:remove(B, Skel);
                 (B, Cells, Skel) ->
                      ByCell = lists:sort(maps:to_list(Cells)),
                      Skel#{B => {[C || {C, _} <- ByCell], ByCell}}
              end, Skeleton, In).

%% Touched: the buckets edited so far, each its cells => members. The
%% members of each of Cells edited by Edit (a cell left empty goes).
edit_all(Cells, NB, Edit, Skeleton, Touched) ->
    lists:foldl(fun(C, Acc) ->
                        B = bucket(C, NB),
                        ByCell = case Acc of
                                     #{B := M} -> M;
                                     #{} -> case Skeleton of
                                                #{B := {_, L}} -> maps:from_list(L);
                                                #{} -> #{}
                                            end
                                 end,
                        ByCell1 = case Edit(maps:get(C, ByCell, [])) of
                                      [] -> maps:remove(C, ByCell);
                                      Is -> ByCell#{C => Is}
                                  end,
                        Acc#{B => ByCell1}
                end, Touched, Cells).

%% One member's payload for the buckets, and what cell_spans/4 needs.
member_write(Writer, #sphere{idx = Idx, radius = R} = S, T0, Packed, Ccd, Grid) ->
    Extents = case Ccd of
                  false -> rw_states:extents(Packed);
                  true ->
                      {X, Y, Z} = rw_states:position(Packed, 1),
                      extend(1, rw_states:count(Packed), Packed, X, Y, Z, X, Y, Z)
              end,
    {{Idx, Writer, S, T0, rw_states:for_probes(Packed), on_grid(bounds(Extents, R), Grid)}, {Packed, Extents, R}}.

%% A write as one bucket of several needs it: with the payloads of only
%% the members in its cells (each bucket copies and keeps what it gets).
-spec for_bucket(rw_cells:write(), [rw_cells:span()]) -> rw_cells:write().
for_bucket({Writer, T0, Payloads, Bounds} = Write, Spans) ->
    case lists:usort([Idx || {_, _, _, Ms} <- Spans, {Idx, _, _} <- Ms]) of
        Idxs when length(Idxs) =:= map_size(Payloads) -> Write;
        Idxs -> {Writer, T0, maps:with(Idxs, Payloads), Bounds}
    end.

%% What the buckets of a plan found, together: the earliest substep with
%% contacts (or Last) and the contacts there, a pair found in several
%% buckets once.
-spec first_contacts([{non_neg_integer(), [rw_cells:hit()]} | none], non_neg_integer()) ->
          {non_neg_integer(), [rw_cells:hit()]}.
first_contacts(Results, Last) ->
    case [R || R <- Results, R =/= none] of
        [] -> {Last, []};
        Found ->
            TStar = lists:min([T || {T, _} <- Found]),
            {TStar, [H || {_, H} <- lists:ukeysort(1, [{{I, element(1, E)}, H}
                                                        || {T, Hs} <- Found, T =:= TStar, {I, E, _} = H <- Hs])]}
    end.

%% The buckets and cells holding the writes Where (of states to delete), in
%% bucket order.
-spec delete(where()) -> [{non_neg_integer(), [rw_hash:cell()]}].
delete(Where) ->
    ByBucket = lists:foldl(fun({B, Cells}, Acc) -> maps:update_with(B, fun(Cs) -> Cells ++ Cs end, Cells, Acc) end,
                           #{}, Where),
    [{B, lists:usort(Cells)} || {B, Cells} <- lists:sort(maps:to_list(ByBucket))].

%% The box around boxes.
union([{X0, Y0, Z0, X1, Y1, Z1} | Rest]) ->
    lists:foldl(fun({A0, B0, C0, A1, B1, C1}, {U0, V0, W0, U1, V1, W1}) ->
                        {min(A0, U0), min(B0, V0), min(C0, W0), max(A1, U1), max(B1, V1), max(C1, W1)}
                end, {X0, Y0, Z0, X1, Y1, Z1}, Rest).

%% A box that holds the sphere at every state of a step (swept over each
%% substep with CCD), padded against rounding: the buckets skip the
%% narrowphase for two writes whose boxes are apart.
bounds({X0, Y0, Z0, X1, Y1, Z1}, R) ->
    Pad = R + 1.0e-9 * (R + lists:max([abs(X0), abs(Y0), abs(Z0), abs(X1), abs(Y1), abs(Z1)])),
    {X0 - Pad, Y0 - Pad, Z0 - Pad, X1 + Pad, Y1 + Pad, Z1 + Pad}.

%% The buckets compare boxes of writes and payloads at every probe, many
%% more times than boxes are made: they get them rounded outwards to a grid
%% of 1/Grid m, as integers, which compare without a float's indirection
%% and take a third of the words. A rounded box holds the exact one, so
%% boxes apart on the grid are apart; Grid is a power of two (the products
%% are exact) of about 64 per cell, at least 1, and coordinates beyond
%% ?FAR m go to the grid's ends.
-define(FAR, 1.0e12).
-define(GRID_END, 16#100000000000000).
-spec grid(float()) -> float().
grid(CellSize) ->
    math:pow(2, max(0, min(16, round(math:log2(64 / CellSize))))).

%% The integer box on the grid of 1/Grid m that holds a box.
-spec on_grid(rw_shape:box6(), float()) -> rw_cells:bounds().
on_grid({X0, Y0, Z0, X1, Y1, Z1}, Grid) ->
    {low(X0, Grid), low(Y0, Grid), low(Z0, Grid), high(X1, Grid), high(Y1, Grid), high(Z1, Grid)}.

low(X, _Grid) when X < -?FAR -> -?GRID_END;
low(X, Grid) -> floor(min(X, ?FAR) * Grid).

high(X, _Grid) when X > ?FAR -> ?GRID_END;
high(X, Grid) -> ceil(max(X, -?FAR) * Grid).

%% The extents of the positions, swept over each substep (CCD: the packed
%% states hold the displacements).
extend(I, N, _Packed, X0, Y0, Z0, X1, Y1, Z1) when I > N -> {X0, Y0, Z0, X1, Y1, Z1};
extend(I, N, Packed, X0, Y0, Z0, X1, Y1, Z1) ->
    {X, Y, Z} = rw_states:position(Packed, I),
    {DX, DY, DZ} = rw_states:displacement(Packed, I),
    {Xa, Ya, Za} = {min(X, X + DX), min(Y, Y + DY), min(Z, Z + DZ)},
    {Xb, Yb, Zb} = {max(X, X + DX), max(Y, Y + DY), max(Z, Z + DZ)},
    extend(I + 1, N, Packed, min(X0, Xa), min(Y0, Ya), min(Z0, Za), max(X1, Xb), max(Y1, Yb), max(Z1, Zb)).

%% For each cell a member's box (swept with CCD) touches during the step,
%% the first and last substep at which it does. The box around all of the
%% step's boxes is the box of its extents padded by R (rounding is
%% monotonic). When that is the first state's box, every state keeps its
%% cells and the step is one run; when it holds at most twice as many
%% cells, one run over all of them is still cheaper than following each
%% state (a bucket tests a pair's distance at every substep anyway, so a
%% wider span adds candidates, never contacts). Otherwise (a fast body)
%% cells are enumerated only when the box changes, and a box is hashed
%% again only when it leaves the region that keeps its cells. A state
%% swept over many cells takes the cells its sphere can touch on the way
%% (rw_hash:swept_cells/4), not its whole box: a sphere crossing cells
%% diagonally would cover the cube of its move.
cell_spans(T0, {Packed, Extents, R}, C, Dt) ->
    Box = rw_hash:box(aabb(Packed, 1, R), C),
    All = all_box(Extents, R, C),
    N = rw_states:count(Packed),
    case (All =:= Box orelse rw_hash:box_size(All) =< 2 * rw_hash:box_size(Box)) andalso not wide(All, Packed, 1) of
        true -> add_run(All, T0, T0 + (N - 1) * Dt, #{});
        false -> spans(1, N, Packed, T0, none, rw_hash:no_region(), T0, T0, {C, R, Dt}, #{})
    end.

%% State I of N of the step (at substep T) and the rest. Box is the cells
%% of the run from Ta to Tb (none after a wide state, a run of its own).
spans(I, N, _Packed, _T, Box, _Region, Ta, Tb, _CRDt, Acc) when I > N ->
    add_run(Box, Ta, Tb, Acc);
spans(I, N, Packed, T, Box, Region, Ta, Tb, {C, R, Dt} = CRDt, Acc) ->
    AABB = aabb(Packed, I, R),
    case rw_hash:in_region(AABB, Region) of
        true -> spans(I + 1, N, Packed, T + Dt, Box, Region, Ta, T, CRDt, Acc);
        false ->
            case rw_hash:box(AABB, C) of
                Box -> spans(I + 1, N, Packed, T + Dt, Box, Region, Ta, T, CRDt, Acc);
                New ->
                    Acc1 = add_run(Box, Ta, Tb, Acc),
                    case wide(New, Packed, I) of
                        false -> spans(I + 1, N, Packed, T + Dt, New, rw_hash:region(New, C), T, T, CRDt, Acc1);
                        true ->
                            Cells = rw_hash:swept_cells(rw_states:position(Packed, I),
                                                        rw_states:displacement(Packed, I), R, C),
                            spans(I + 1, N, Packed, T + Dt, none, rw_hash:no_region(), T, T, CRDt,
                                  add_cells(Cells, T, T, Acc1))
                    end
            end
    end.

%% A box of many cells around a swept state, whose own cells are fewer.
wide(Box, Packed, I) -> rw_hash:cut(Box) andalso rw_states:displacement(Packed, I) =/= undefined.

add_run(none, _Ta, _Tb, Acc) -> Acc;
add_run(Box, Ta, Tb, Acc) -> add_cells(rw_hash:box_cells(Box), Ta, Tb, Acc).

add_cells(Cells, Ta, Tb, Acc) ->
    Spans = lists:foldl(fun(C, A) -> case A of
                                         #{C := {First, _}} -> A#{C => {First, Tb}};
                                         _ -> A#{C => {Ta, Tb}}
                                     end
                        end, Acc, Cells),
    map_size(Spans) =< ?MAX_WRITE_CELLS orelse
        error({too_many_cells,
               lists:flatten(io_lib:format("a sphere's write to the TVHT covers more than ~b cells, the most a write "
                                           "may hold: it moves faster than its scene's energy allowed at validation",
                                           [?MAX_WRITE_CELLS]))}),
    Spans.

%% The most cells one member's write covers; past it the write raises
%% error({too_many_cells, Message}). Each cell is a span here and a
%% segment in its bucket: a lone sphere writing this many took some
%% 500 MB (its heap and the buckets', as the allocators keep them).
-spec max_write_cells() -> pos_integer().
max_write_cells() -> ?MAX_WRITE_CELLS.

%% The box around state I of a step (swept over its substep with CCD).
aabb(Packed, I, R) ->
    case rw_states:displacement(Packed, I) of
        undefined -> rw_shape:sphere_aabb(rw_states:position(Packed, I), R);
        Disp -> rw_shape:swept_aabb(rw_states:position(Packed, I), Disp, R)
    end.

%% The members' cell spans (Idx and Cell => {Ta, Tb}) by cell and bucket,
%% in bucket order (the lock order).
plan(MemberSpans, NB) ->
    ByCell = lists:foldl(fun({Idx, Spans}, Acc) ->
                                 maps:fold(fun(Cell, {Ta, Tb}, A) ->
                                                   maps:update_with(Cell, fun(L) -> [{Idx, Ta, Tb} | L] end,
                                                                    [{Idx, Ta, Tb}], A)
                                           end, Acc, Spans)
                         end, #{}, MemberSpans),
    ByBucket = maps:fold(fun(Cell, [{_, Ta0, Tb0} | _] = Ms, Acc) ->
                                 {Ta, Tb} = lists:foldl(fun({_, A, B}, {L, H}) -> {min(A, L), max(B, H)} end,
                                                        {Ta0, Tb0}, Ms),
                                 maps:update_with(bucket(Cell, NB), fun(L) -> [{Cell, Ta, Tb, lists:sort(Ms)} | L] end,
                                                  [{Cell, Ta, Tb, lists:sort(Ms)}], Acc)
                         end, #{}, ByCell),
    %% (cells and each cell's members in order: the same plan whatever the
    %% order of the maps, and as write/8 moves members in its last plan)
    [begin
         Sorted = lists:sort(Spans),
         {B, [C || {C, _, _, _} <- Sorted], Sorted}
     end || {B, Spans} <- lists:sort(maps:to_list(ByBucket))].

%% A pool of NB buckets on one node, or a placement over several (rw_place).
bucket(Cell, NB) when is_integer(NB) -> rw_hash:bucket(Cell, NB);
bucket(Cell, Place) -> rw_place:bucket(Cell, Place).
