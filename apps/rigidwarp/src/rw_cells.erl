%% The contents of one TVHT bucket (pure): per cell and writer the
%% segments of the writers' steps, the narrowphase of a write against the
%% other writers' states at the same LVT in the same cell, the contacts
%% reported, and what a delete invalidates. rw_bucket is the process that
%% holds one and serialises access to its cells with locks.
%%
%% Keeping a group's members together per cell lets a probe skip its own
%% group with one comparison, and a foreign group whose write lies apart
%% from its own with one more (Cylinders' rows of piles share cells but
%% never touch); only then are member pairs compared, by time and box.
%% Contacts among the members of one write are not its business: the
%% writer finds those itself (rw_island).
%%
%% The segments can live in the Erlang map below or, for a bucket, in C
%% (rw_native:cells_new/0, c_src/rw_cells.c), outside its heap: tens of
%% thousands of bodies leave each bucket hundreds of thousands of words of
%% segments, which its collections would copy again and again. The C store
%% does the bookkeeping in integers (which segments a write meets, storing,
%% truncating, sweeping) and, without CCD, the first-touch scan of the pairs
%% it finds, handing back only the earliest; it changes in place, so such
%% cells() must be used linearly. The contacts are made here either way,
%% and both stores give the same answers (rw_cells_tests).
-module(rw_cells).
-include("rigidwarp.hrl").
-export([new/2, new/3, probe/3, store/7, delete/5, gc/2, sweep_every/1, contact_ids/3, contents/1]).
-export_type([cells/0, ids/0, cid/0, write/0, payload/0, span/0, member_span/0, hit/0, entry/0, bounds/0]).

%% One step's states of one member: T0 is the LVT of the first state,
%% States (and, with CCD, the free displacements) hold one per substep,
%% Bounds is a box that holds the sphere (swept, with CCD) at all of them.
-type payload() :: {Idx :: non_neg_integer(), Writer :: term(), #sphere{}, T0 :: non_neg_integer(),
                    States :: rw_states:packed(), Bounds :: bounds()}.
%% (on a grid of integers, rounded outwards: rw_tvht_plan)
-type bounds() :: {integer(), integer(), integer(), integer(), integer(), integer()}.
%% One entity's step: the writer, its first substep, its members' payloads
%% and a box that holds them all.
-type write() :: {Writer :: term(), T0 :: non_neg_integer(), #{non_neg_integer() => payload()}, bounds()}.
%% A cell touched by the write from Ta to Tb, and by each member from its
%% own Ta to Tb.
-type span() :: {rw_hash:cell(), Ta :: non_neg_integer(), Tb :: non_neg_integer(), [member_span()]}.
-type member_span() :: {Idx :: non_neg_integer(), Ta :: non_neg_integer(), Tb :: non_neg_integer()}.
%% One body's state at one LVT, as the narrowphase sees it.
-type entry() :: {Idx :: non_neg_integer(), Writer :: term(), #sphere{}, #st{}, Disp :: rw_vec:vec() | undefined}.
%% A contact found by the narrowphase between the writer's member MyIdx and
%% another body, in canonical order (lower idx first).
-type hit() :: {MyIdx :: non_neg_integer(), entry(), #contact{}}.

-type cid() :: {non_neg_integer(), non_neg_integer(), non_neg_integer(), term()}.
%% The ids of the contacts at T between the writer's members and other
%% bodies, by {member idx, partner idx}.
-type ids() :: #{{non_neg_integer(), non_neg_integer()} => cid()}.
%% A write's presence in one cell, from Ta to Tb, with the write's box
%% beside the times: a probe reads both of every other writer's newest
%% segments in its cells, and at tens of thousands of bodies each read
%% from the write behind it would miss the cache.
-record(seg, {ta :: non_neg_integer(), tb :: non_neg_integer(),
              x0 :: integer(), y0 :: integer(), z0 :: integer(), x1 :: integer(), y1 :: integer(), z1 :: integer(),
              write :: write(), members :: [member_span()]}).
-type seg() :: #seg{}.
%% A cell as a key of the bucket's map (key/1).
-type cell_key() :: non_neg_integer() | rw_hash:cell().

-record(cells, {
    model :: #model{},
    dt :: pos_integer(),                     % substep, ticks
    %% per cell, per writer, its segments newest first: an entity writes
    %% forward in time and a rollback cuts the newest ones, so each list is
    %% sorted and a probe near the present reads only its head (or the
    %% same in C)
    cells = #{} :: #{cell_key() => #{term() => [seg()]}} | {native, rw_native:cells()},
    %% contacts reported from this bucket, by body: [{T, Cid}]
    by_body = #{} :: #{non_neg_integer() => [{non_neg_integer(), cid()}]},
    contacts = #{} :: #{cid() => {Detector :: term(), Other :: term()}},
    gc_at = 0 :: non_neg_integer()
}).
-opaque cells() :: #cells{}.

%% Cells in the Erlang map: a value like any other.
-spec new(#model{}, pos_integer()) -> cells().
new(Model, Dt) -> new(Model, Dt, erlang).

%% Cells in the Erlang map or in C (changed in place: use each value once).
-spec new(#model{}, pos_integer(), erlang | native) -> cells().
new(Model, Dt, erlang) -> #cells{model = Model, dt = Dt};
new(Model, Dt, native) -> #cells{model = Model, dt = Dt, cells = {native, rw_native:cells_new()}}.

%% Every segment, whichever the store: {cell's key, writer, [{Ta, Tb,
%% write's box, write's T0, member spans}]} newest first, sorted. (A box
%% with a corner past 64 bits reads as all of space, as the C store keeps
%% it: a box only ever rules pairs out.)
-spec contents(cells()) ->
          [{cell_key(), term(), [{non_neg_integer(), non_neg_integer(), bounds(), non_neg_integer(), [member_span()]}]}].
contents(#cells{cells = {native, Store}}) ->
    lists:sort([{key(Cell), Owner, Segs} || {Cell, Owner, Segs} <- rw_native:cells_dump(Store)]);
contents(#cells{cells = Cells}) ->
    lists:sort([{Key, Owner, [{Ta, Tb, box64({X0, Y0, Z0, X1, Y1, Z1}), T0, Ms}
                              || #seg{ta = Ta, tb = Tb, x0 = X0, y0 = Y0, z0 = Z0, x1 = X1, y1 = Y1, z1 = Z1,
                                      write = {_, T0, _, _}, members = Ms} <- Segs]}
                || {Key, ByW} <- maps:to_list(Cells), {Owner, Segs} <- maps:to_list(ByW)]).

%% The ids of the contacts at T between the writer's members and other
%% bodies, {T, lower idx, higher idx, unique}, with one fresh term per pair
%% from Uniques.
-spec contact_ids(non_neg_integer(), [{non_neg_integer(), non_neg_integer()}], [term()]) -> ids().
contact_ids(T, Pairs, Uniques) ->
    maps:from_list([{{Idx, OIdx}, {T, min(Idx, OIdx), max(Idx, OIdx), U}} || {{Idx, OIdx}, U} <- lists:zip(Pairs, Uniques)]).

%% A box as the C store keeps it: all of space where a corner does not
%% fit 64 bits.
-define(INT64_MIN, -16#8000000000000000).
-define(INT64_MAX, 16#7FFFFFFFFFFFFFFF).
box64(Box) ->
    case lists:all(fun(C) -> C >= ?INT64_MIN andalso C =< ?INT64_MAX end, tuple_to_list(Box)) of
        true -> Box;
        false -> {?INT64_MIN, ?INT64_MIN, ?INT64_MIN, ?INT64_MAX, ?INT64_MAX, ?INT64_MAX}
    end.

%% Nothing before GVT can change any more: forget it (now and then: a
%% sweep costs a pass over every segment, done when GVT has moved on by
%% sweep_every/1 since the last).
-spec gc(non_neg_integer(), cells()) -> cells().
gc(Gvt, #cells{gc_at = At} = S) when Gvt < At -> S;
gc(Gvt, #cells{cells = Cells, by_body = By, contacts = C, dt = Dt} = S) ->
    By1 = maps:filtermap(fun(_, L) ->
                                 case [X || {T, _} = X <- L, T >= Gvt] of
                                     [] -> false;
                                     Kept -> {true, Kept}
                                 end
                         end, By),
    C1 = maps:filter(fun({T, _, _, _}, _) -> T >= Gvt end, C),
    S#cells{cells = sweep(Gvt, Cells), by_body = By1, contacts = C1, gc_at = Gvt + sweep_every(Dt)}.

sweep(Gvt, {native, Store} = Cells) ->
    ok = rw_native:cells_gc(Store, Gvt),
    Cells;
sweep(Gvt, Cells) ->
    Recent = fun(_, Segs) ->
                     case lists:takewhile(fun(#seg{tb = Tb}) -> Tb >= Gvt end, Segs) of
                         [] -> false;
                         Kept -> {true, Kept}
                     end
             end,
    maps:filtermap(fun(_, ByWriter) ->
                           case maps:filtermap(Recent, ByWriter) of
                               Empty when map_size(Empty) =:= 0 -> false;
                               Kept -> {true, Kept}
                           end
                   end, Cells).

%% How far GVT moves between two sweeps: 32 substeps of Dt ticks.
-spec sweep_every(pos_integer()) -> pos_integer().
sweep_every(Dt) -> 32 * Dt.

%% The earliest LVT at which one of the written members touches another
%% body's state in one of its cells, with every contact at that LVT. Member
%% pairs meet in several cells: their windows are merged first, so that
%% each pair is checked once, and not at all when their boxes are apart.
-spec probe(write(), [span()], cells()) -> {non_neg_integer(), [hit()]} | none.
probe(Write, Spans, #cells{cells = {native, Store}, model = #model{ccd = Ccd}, dt = Dt} = S) ->
    Scan = case Ccd of
               false -> Dt;
               true -> 0
           end,
    scan_found(rw_native:cells_probe(Store, Write, Spans, Scan), Write, none, S);
probe({Me, _, _, Bounds} = Write, Spans, #cells{cells = Cells} = S) ->
    scan_windows(maps:to_list(span_windows(Spans, Cells, Me, Bounds, #{})), Write, none, S).

%% The windows the C store gave back, scanned (without CCD, each of the
%% earliest touches it found is the window of its one substep).
scan_found([], _Write, Best, _S) -> Best;
scan_found([{I, _, Lo, Hi, Other} | Rest], {_, _, Members, _} = Write, Best, S) ->
    scan_found(Rest, Write, scan(Lo, bound(Hi, Best), maps:get(I, Members), Other, Best, S), S).

span_windows([], _Cells, _Me, _Bounds, Acc) -> Acc;
span_windows([{Cell, Ta, Tb, Ms} | Rest], Cells, Me, Bounds, Acc) ->
    Key = key(Cell),
    case Cells of
        %% (maps:to_list is one BIF call; maps:fold steps an iterator in
        %% Erlang)
        #{Key := ByWriter} ->
            span_windows(Rest, Cells, Me, Bounds, cell_windows(maps:to_list(ByWriter), Me, Bounds, Ta, Tb, Ms, Acc));
        _ ->
            span_windows(Rest, Cells, Me, Bounds, Acc)
    end.

%% The other writers in a cell (not the prober's own earlier writes).
cell_windows([], _Me, _Bounds, _Ta, _Tb, _Ms, Acc) -> Acc;
cell_windows([{Me, _} | Rest], Me, Bounds, Ta, Tb, Ms, Acc) -> cell_windows(Rest, Me, Bounds, Ta, Tb, Ms, Acc);
cell_windows([{_, Segs} | Rest], Me, Bounds, Ta, Tb, Ms, Acc) ->
    cell_windows(Rest, Me, Bounds, Ta, Tb, Ms, segs(Segs, Bounds, Ta, Tb, Ms, Acc)).

%% A writer's segments in the cell, newest first: skip those after the
%% window, stop at the first one before it; for each that overlaps it, and
%% whose write is not apart from the prober's, the member pairs that meet
%% in time.
segs([], _Bounds, _Ta, _Tb, _Ms, Acc) -> Acc;
segs([#seg{tb = OTb} | _], _Bounds, Ta, _Tb, _Ms, Acc) when OTb < Ta -> Acc;
segs([#seg{ta = OTa} | Rest], Bounds, Ta, Tb, Ms, Acc) when OTa > Tb -> segs(Rest, Bounds, Ta, Tb, Ms, Acc);
segs([#seg{x0 = BX0, y0 = BY0, z0 = BZ0, x1 = BX1, y1 = BY1, z1 = BZ1, write = W, members = OMs} | Rest],
     {AX0, AY0, AZ0, AX1, AY1, AZ1} = Bounds, Ta, Tb, Ms, Acc) ->
    Acc1 = case disjoint(AX0, AY0, AZ0, AX1, AY1, AZ1, BX0, BY0, BZ0, BX1, BY1, BZ1) of
               true -> Acc;
               false -> member_windows(Ms, OMs, W, Acc)
           end,
    segs(Rest, Bounds, Ta, Tb, Ms, Acc1).

%% Windows keyed by member and other member (pair_key/2: an integer, as
%% map keys are compared at every lookup), per other write's T0.
member_windows([], _OMs, _W, Acc) -> Acc;
member_windows([{I, A, B} | Rest], OMs, W, Acc) ->
    member_windows(Rest, OMs, W, pair_windows(OMs, I, A, B, W, Acc)).

%% (times are integers: the guards stand for max/2 and min/2, which are
%% calls)
pair_windows([], _I, _A, _B, _W, Acc) -> Acc;
pair_windows([{O, OA, OB} | Rest], I, A, B, {_, OT0, _, _} = W, Acc) ->
    Lo = if OA > A -> OA; true -> A end,
    Hi = if OB < B -> OB; true -> B end,
    Acc1 = if
               Lo > Hi -> Acc;
               true ->
                   Key = pair_key(I, O),
                   case Acc of
                       #{Key := Ws} -> Acc#{Key := window(OT0, W, Lo, Hi, Ws)};
                       _ -> Acc#{Key => [{OT0, W, Lo, Hi}]}
                   end
           end,
    pair_windows(Rest, I, A, B, W, Acc1).

%% (a scene's bodies by rank: indices far below 2^24)
-define(PAIR, 16#1000000).
pair_key(I, O) when O < ?PAIR -> I * ?PAIR + O.

%% The window on the other write at OT0 widened by Lo..Hi.
window(OT0, W, Lo, Hi, [{OT0, _, L, H} | Rest]) -> [{OT0, W, min(L, Lo), max(H, Hi)} | Rest];
window(OT0, W, Lo, Hi, [Other | Rest]) -> [Other | window(OT0, W, Lo, Hi, Rest)];
window(OT0, W, Lo, Hi, []) -> [{OT0, W, Lo, Hi}].

scan_windows([], _Write, Best, _S) -> Best;
scan_windows([{Key, Ws} | Rest], Write, Best, S) ->
    scan_windows(Rest, Write, scan_pair(Key div ?PAIR, Key rem ?PAIR, Ws, Write, Best, S), S).

scan_pair(_I, _O, [], _Write, Best, _S) -> Best;
scan_pair(I, O, [{_, {_, _, OMembers, _}, Lo, Hi} | Ws], {_, _, Members, _} = Write, Best, S) ->
    Mine = maps:get(I, Members),
    Other = maps:get(O, OMembers),
    case apart(Mine, Other) of
        true -> scan_pair(I, O, Ws, Write, Best, S);
        false -> scan_pair(I, O, Ws, Write, scan(Lo, bound(Hi, Best), Mine, Other, Best, S), S)
    end.

bound(Hi, none) -> Hi;
bound(Hi, {BT, _}) -> min(Hi, BT).

%% Two payloads whose boxes do not overlap: they cannot touch.
apart({_, _, _, _, _, {AX0, AY0, AZ0, AX1, AY1, AZ1}}, {_, _, _, _, _, {BX0, BY0, BZ0, BX1, BY1, BZ1}}) ->
    disjoint(AX0, AY0, AZ0, AX1, AY1, AZ1, BX0, BY0, BZ0, BX1, BY1, BZ1).

%% Two boxes, by their corners, that do not overlap.
disjoint(AX0, AY0, AZ0, AX1, AY1, AZ1, BX0, BY0, BZ0, BX1, BY1, BZ1) ->
    AX1 < BX0 orelse BX1 < AX0 orelse AY1 < BY0 orelse BY1 < AY0 orelse AZ1 < BZ0 orelse BZ1 < AZ0.

%% First LVT in [Lo, Hi] at which the two bodies touch. Without CCD the
%% test is a plain distance check on the stored positions, which skips
%% the substeps at which the two are too far apart to touch yet; the
%% contact itself is computed in canonical order only on a hit.
scan(Lo, Hi, _Mine, _Other, Best, _S) when Lo > Hi -> Best;
scan(Lo, Hi, {_, _, #sphere{radius = RA}, T0A, StsA, _} = Mine,
     {_, _, #sphere{radius = RB}, T0B, StsB, _} = Other, Best, #cells{dt = Dt, model = #model{ccd = false}} = S) ->
    case rw_states:first_touch(StsA, (Lo - T0A) div Dt + 1, StsB, (Lo - T0B) div Dt + 1, (Hi - Lo) div Dt,
                               RA + RB) of
        none -> Best;
        K -> hit(Lo + K * Dt, Mine, Other, Best, S)
    end;
scan(T, Hi, _Mine, _Other, Best, _S) when T > Hi -> Best;
scan(T, Hi, Mine, Other, Best, #cells{model = M, dt = Dt} = S) ->
    case contact(M, entry(Mine, T, Dt), entry(Other, T, Dt)) of
        none -> scan(T + Dt, Hi, Mine, Other, Best, S);
        _ -> hit(T, Mine, Other, Best, S)
    end.

hit(T, {Idx, _, _, _, _, _} = Mine, Other, Best, #cells{model = M, dt = Dt}) ->
    B = entry(Other, T, Dt),
    Hit = {Idx, B, contact(M, entry(Mine, T, Dt), B)},
    case Best of
        {T, Hits} ->
            OIdx = element(1, B),
            case lists:any(fun({I, {O, _, _, _, _}, _}) -> I =:= Idx andalso O =:= OIdx end, Hits) of
                true -> Best;
                false -> {T, [Hit | Hits]}
            end;
        _ -> {T, [Hit]}
    end.

entry({Idx, Pid, Sphere, T0, States, _}, T, Dt) ->
    I = (T - T0) div Dt + 1,
    {Idx, Pid, Sphere, rw_states:state(States, I), rw_states:displacement(States, I)}.

%% Narrowphase in canonical order: the lower index first.
contact(M, {IA, _, _, _, _} = A, {IB, _, _, _, _} = B) when IA < IB -> narrow(M, A, B);
contact(M, A, B) -> narrow(M, B, A).

narrow(#model{ccd = false}, {_, _, #sphere{radius = RA}, #st{p = PA}, _}, {_, _, #sphere{radius = RB}, #st{p = PB}, _}) ->
    rw_narrow:sphere_sphere(PA, RA, PB, RB);
narrow(#model{ccd = true}, {_, _, #sphere{radius = RA}, #st{p = PA}, DA},
       {_, _, #sphere{radius = RB}, #st{p = PB}, DB}) ->
    rw_narrow:swept_sphere_sphere(PA, DA, RA, PB, DB, RB).

%% Store the probed write's segments up to UpTo, and the contacts it found
%% there (in this bucket).
-spec store(term(), write(), [span()], {non_neg_integer(), [hit()]} | none,
            non_neg_integer(), ids(), cells()) -> cells().
store(Owner, Write, Spans, Result, UpTo, Ids, #cells{cells = Cells} = S) ->
    S1 = case Cells of
             {native, Store} ->
                 ok = rw_native:cells_store(Store, Owner, Write, Spans, UpTo),
                 S;
             _ ->
                 S#cells{cells = store_spans(Spans, Owner, Write, UpTo, Cells)}
         end,
    case Result of
        {UpTo, Hits} ->
            lists:foldl(fun({Idx, {OIdx, OPid, _, _, _}, _}, Acc) ->
                                record(maps:get({Idx, OIdx}, Ids), UpTo, Idx, Owner, OIdx, OPid, Acc)
                        end, S1, Hits);
        _ ->
            S1
    end.

store_spans([], _Owner, _Write, _UpTo, Cells) -> Cells;
store_spans([{Cell, Ta, Tb, Ms} | Spans], Owner, {_, _, _, {X0, Y0, Z0, X1, Y1, Z1}} = Write, UpTo, Cells)
  when Ta =< UpTo ->
    Key = key(Cell),
    Seg = #seg{ta = Ta, tb = min(Tb, UpTo), x0 = X0, y0 = Y0, z0 = Z0, x1 = X1, y1 = Y1, z1 = Z1, write = Write,
               members = [{I, A, min(B, UpTo)} || {I, A, B} <- Ms, A =< UpTo]},
    Cells1 = case Cells of
                 #{Key := #{Owner := Segs} = ByW} -> Cells#{Key := ByW#{Owner := [Seg | Segs]}};
                 #{Key := ByW} -> Cells#{Key := ByW#{Owner => [Seg]}};
                 _ -> Cells#{Key => #{Owner => [Seg]}}
             end,
    store_spans(Spans, Owner, Write, UpTo, Cells1);
store_spans([_ | Spans], Owner, Write, UpTo, Cells) ->
    store_spans(Spans, Owner, Write, UpTo, Cells).

record(Cid, T, Idx, Detector, OIdx, Other, #cells{by_body = By, contacts = C} = S) ->
    Add = fun(L) -> [{T, Cid} | L] end,
    By1 = maps:update_with(OIdx, Add, [{T, Cid}], maps:update_with(Idx, Add, [{T, Cid}], By)),
    S#cells{by_body = By1, contacts = C#{Cid => {Detector, Other}}}.

%% Delete Owner's states after R in the cells Owned; return the contacts
%% its members Idxs had there after R (once each).
-spec delete(term(), [non_neg_integer()], non_neg_integer(), [rw_hash:cell()], cells()) ->
          {[{cid(), term(), term()}], cells()}.
delete(Owner, Idxs, R, Owned, #cells{cells = Cells, by_body = By, contacts = C} = S) ->
    Cells1 = truncate_owned(Owner, R, Owned, Cells),
    {Gone, By1} = lists:foldl(fun(Idx, {G, B}) ->
                                      case lists:partition(fun({T, _}) -> T > R end, maps:get(Idx, B, [])) of
                                          {G1, []} -> {G1 ++ G, maps:remove(Idx, B)};
                                          {G1, Kept} -> {G1 ++ G, B#{Idx => Kept}}
                                      end
                              end, {[], By}, Idxs),
    Lost = lists:ukeysort(1, [{Cid, D, O} || {_, Cid} <- Gone, {D, O} <- [maps:get(Cid, C, none)]]),
    {Lost, S#cells{cells = Cells1, by_body = By1, contacts = maps:without([Cid || {_, Cid} <- Gone], C)}}.

truncate_owned(Owner, R, Owned, {native, Store} = Cells) ->
    ok = rw_native:cells_delete(Store, Owner, R, Owned),
    Cells;
truncate_owned(Owner, R, Owned, Cells) ->
    lists:foldl(fun(Cell, Acc) ->
                        Key = key(Cell),
                        case Acc of
                            #{Key := #{Owner := Segs} = ByW} ->
                                case truncate(Segs, R) of
                                    [] when map_size(ByW) =:= 1 -> maps:remove(Key, Acc);
                                    [] -> Acc#{Key := maps:remove(Owner, ByW)};
                                    Kept -> Acc#{Key := ByW#{Owner := Kept}}
                                end;
                            _ -> Acc
                        end
                end, Cells, Owned).

%% A cell's key in the bucket's map: one integer for the cells within
%% 2^18 of the origin on every axis (hashed and compared as one word),
%% else the cell itself.
-define(KEY_OFFSET, 16#40000).
key({X, Y, Z}) when X >= -?KEY_OFFSET, X < ?KEY_OFFSET, Y >= -?KEY_OFFSET, Y < ?KEY_OFFSET,
                    Z >= -?KEY_OFFSET, Z < ?KEY_OFFSET ->
    ((X + ?KEY_OFFSET) bsl 38) bor ((Y + ?KEY_OFFSET) bsl 19) bor (Z + ?KEY_OFFSET);
key(Cell) -> Cell.

%% A writer's segments (newest first) end at R at the latest.
truncate([#seg{ta = Ta} | Rest], R) when Ta > R -> truncate(Rest, R);
truncate([#seg{tb = Tb, members = Ms} = Seg | Rest], R) when Tb > R ->
    [Seg#seg{tb = R, members = [{I, A, min(B, R)} || {I, A, B} <- Ms, A =< R]} | Rest];
truncate(Segs, _R) -> Segs.

