%% The cells of a bucket kept in C (rw_native:cells_new/0) against the same
%% kept in the Erlang map: after every write, delete and sweep of random
%% bodies flying through a few cells, the same segments, and every probe
%% finds the same first contacts (bit for bit: floats compared in the
%% external format).
-module(rw_cells_tests).
-include_lib("proper/include/proper.hrl").
-include_lib("eunit/include/eunit.hrl").
-include_lib("rw_physics/include/rw_physics.hrl").
-export([ops/0, run/2]).

-define(CELL, 1.0).
-define(DT, 1).

native_cells_are_the_erlang_cells_test_() ->
    case rw_native:loaded() of
        false ->
            [];
        true ->
            {timeout, 120,
             fun() ->
                     ?assert(proper:quickcheck(prop_same(#model{}), [{numtests, 300}, {to_file, user}])),
                     ?assert(proper:quickcheck(prop_same(#model{ccd = true}), [{numtests, 100}, {to_file, user}]))
             end}
    end.

%% Far out, cells and boxes past 64 bits: the C store keeps the cells as
%% terms and reads such boxes as all of space; the answers are the same.
far_cells_test() ->
    case rw_native:loaded() of
        false ->
            ok;
        true ->
            Far = 1.0e22,
            Ops = [{write, a, 0, [{0, {Far, 0.0, 0.0}, {1.0, 0.0, 0.0}}], 8},
                   {write, b, 0, [{1, {Far + 3.0, 0.0, 0.0}, {-1.0, 0.0, 0.0}}], 8},
                   {write, c, 0, [{2, {Far + 3.0, 0.5, 0.0}, {-1.0, 0.0, 0.0}}], 8},
                   {delete, b, 2},
                   {write, b, 3, [{1, {Far + 1.0, 0.0, 0.0}, {-1.0, 0.0, 0.0}}], 8},
                   {gc, 4}],
            {Hits, _, _} = run(#model{}, Ops),
            ?assertNotEqual([], [H || H <- Hits, H =/= none])
    end.

%% A span or cell that is not a cell's key is badarg, not enomem, and the
%% call changes nothing: every key is read before the store is touched.
bad_keys_are_badarg_test() ->
    case rw_native:loaded() of
        false ->
            ok;
        true ->
            Model = #model{},
            {Write, Spans} = write(Model, a, 0, [{0, {0.0, 0.0, 0.0}, {100.0, 0.0, 0.0}}], 8),
            ?assert(length(Spans) >= 2),
            Store = rw_native:cells_new(),
            ok = rw_native:cells_store(Store, a, Write, Spans, 7),
            Before = rw_native:cells_dump(Store),
            {Cell, Ta, Tb, Ms} = lists:last(Spans),
            [begin
                 BadSpans = lists:droplast(Spans) ++ [{Bad, Ta, Tb, Ms}],
                 ?assertError(badarg, rw_native:cells_store(Store, b, Write, BadSpans, 7)),
                 ?assertError(badarg, rw_native:cells_probe(Store, Write, BadSpans, 1)),
                 ?assertError(badarg, rw_native:cells_delete(Store, a, 0, [element(1, hd(Spans)), Bad])),
                 ?assertEqual(Before, rw_native:cells_dump(Store))
             end || Bad <- [{1, 2}, {a, 0, 0}, {0, 0, "1"}, not_a_cell]],
            %% (a cell past 64 bits is a key)
            ok = rw_native:cells_delete(Store, a, 0, [Cell, {1 bsl 70, 0, 0}]),
            ?assertNotEqual(Before, rw_native:cells_dump(Store))
    end.

%% A store of tens of thousands of cells is swept in slices (calls of at
%% most half a time slice each, rw_native:cells_gc/2 calling again): the
%% same segments as the Erlang store keeps, and the cells left empty gone;
%% a group's write of 70 members left without segments is freed on a dirty
%% scheduler (rw_native's nif_cells_free/1).
large_sweep_test_() ->
    case rw_native:loaded() of
        false -> [];
        true -> {timeout, 120, fun large_sweep/0}
    end.

large_sweep() ->
    Model = #model{},
    Group = [{2000 + K, {-50.0 - 0.6 * K, 0.0, 0.0}, {1.0, 0.0, 0.0}} || K <- lists:seq(1, 70)],
    Writes = [{group, 0, write(Model, group, 0, Group, 12)}]
             ++ [{Owner, T0, write(Model, Owner, T0, [Body], 12)}
                 || I <- lists:seq(1, 1000), T0 <- [0, 12], Owner <- [{owner, I}],
                    Body <- [{I, {10.0 * (I rem 60), 10.0 * (I div 60) + 0.4 * T0, 0.0}, {300.0, 0.0, 0.0}}]],
    Store = fun(S0) ->
                    lists:foldl(fun({Owner, T0, {Write, Spans}}, S) ->
                                        rw_cells:store(Owner, Write, Spans, none, T0 + 11, #{}, S)
                                end, S0, Writes)
            end,
    {E, N} = {Store(rw_cells:new(Model, ?DT, erlang)), Store(rw_cells:new(Model, ?DT, native))},
    Before = rw_cells:contents(N),
    ?assertEqual(rw_cells:contents(E), Before),
    Counted = [{rw_native, nif_cells_gc, 3}, {rw_native, nif_cells_free, 1}],
    _ = [erlang:trace_pattern(MFA, true, [call_count]) || MFA <- Counted],
    {E1, N1} = try {rw_cells:gc(12, E), rw_cells:gc(12, N)}
               after
                   [{call_count, Slices}, {call_count, Frees}] = [erlang:trace_info(MFA, call_count) || MFA <- Counted],
                   _ = [erlang:trace_pattern(MFA, false, [call_count]) || MFA <- Counted],
                   ?assert(Slices >= 2),
                   ?assertEqual(1, Frees)
               end,
    Left = rw_cells:contents(N1),
    ?assertEqual(rw_cells:contents(E1), Left),
    ?assert(length(Left) < length(Before)).

prop_same(Model) ->
    ?FORALL(Ops, ops(), begin
                            _ = run(Model, Ops),
                            true
                        end).

%% Run Ops on both stores, asserting at every step; the probes' results.
run(Model, Ops) ->
    lists:foldl(fun(Op, {Hits, E, N}) ->
                        {Hit, E1, N1} = apply_op(Model, Op, E, N),
                        ?assertEqual(rw_cells:contents(E1), rw_cells:contents(N1)),
                        {[Hit | Hits], E1, N1}
                end, {[], rw_cells:new(Model, ?DT, erlang), rw_cells:new(Model, ?DT, native)}, Ops).

apply_op(Model, {write, Owner, T0, Bodies, Substeps}, E, N) ->
    {Write, Spans} = write(Model, Owner, T0, Bodies, Substeps),
    Found = rw_cells:probe(Write, Spans, E),
    ?assertEqual(canonical(Found), canonical(rw_cells:probe(Write, Spans, N))),
    {UpTo, Pairs} = case Found of
                        none -> {T0 + (Substeps - 1) * ?DT, []};
                        {T, Hits} -> {T, [{I, O} || {I, {O, _, _, _, _}, _} <- Hits]}
                    end,
    Ids = rw_cells:contact_ids(UpTo, Pairs, lists:seq(1, length(Pairs))),
    {Found, rw_cells:store(Owner, Write, Spans, Found, UpTo, Ids, E),
     rw_cells:store(Owner, Write, Spans, Found, UpTo, Ids, N)};
apply_op(_Model, {delete, Owner, R}, E, N) ->
    Owned = lists:usort([Cell || {Cell, O, _} <- cells_of(E), O =:= Owner]),
    Idxs = [Idx || {_, O, Segs} <- rw_cells:contents(E), O =:= Owner, {_, _, _, _, Ms} <- Segs, {Idx, _, _} <- Ms],
    {LostE, E1} = rw_cells:delete(Owner, lists:usort(Idxs), R, Owned, E),
    {LostN, N1} = rw_cells:delete(Owner, lists:usort(Idxs), R, Owned, N),
    ?assertEqual(LostE, LostN),
    {none, E1, N1};
apply_op(_Model, {gc, Gvt}, E, N) ->
    {none, rw_cells:gc(Gvt, E), rw_cells:gc(Gvt, N)}.

%% The cells each writer is in (as {X, Y, Z}), read back from its spans.
cells_of(Cells) ->
    [{unkey(Key), Owner, Segs} || {Key, Owner, Segs} <- rw_cells:contents(Cells)].

unkey({_, _, _} = Cell) -> Cell;
unkey(Key) ->
    Off = 16#40000,
    {(Key bsr 38) - Off, ((Key bsr 19) band 16#7FFFF) - Off, (Key band 16#7FFFF) - Off}.

%% A probe's answer with its hits in one order, floats as their bits.
canonical(none) -> none;
canonical({T, Hits}) -> {T, lists:sort([term_to_binary(H, [{minor_version, 2}]) || H <- Hits])}.

%% Owner's write of Bodies ({Idx, Position, Velocity}) flying free for
%% Substeps from T0, and its spans in the one bucket.
write(#model{ccd = Ccd} = Model, Owner, T0, Bodies, Substeps) ->
    Spheres = list_to_tuple([#sphere{idx = Idx, id = integer_to_binary(Idx), radius = 0.25, mass = 1.0, inv_mass = 1.0,
                                     inv_inertia = 16.0} || {Idx, _, _} <- Bodies]),
    Steps = [begin
                 Sts = [#st{p = add(P, scale(V, K * 0.001)), v = V} || K <- lists:seq(0, Substeps - 1)],
                 Disps = case Ccd of
                             true -> [scale(V, 0.001) || _ <- Sts];
                             false -> undefined
                         end,
                 rw_states:pack(Sts, Disps, false, Ccd)
             end || {_, P, V} <- Bodies],
    {Write, [{0, _Cells, Spans}]} = rw_tvht_plan:write(Owner, T0, Spheres, Steps, Model, {?CELL, ?DT}, 1),
    {Write, Spans}.

add({A, B, C}, {X, Y, Z}) -> {A + X, B + Y, C + Z}.
scale({X, Y, Z}, K) -> {X * K, Y * K, Z * K}.

%%% Generators: four writers, each with its own bodies (a writer's
%%% bodies are its own, as an entity's members are), moving through the
%%% cells around the origin fast enough to cross some within a write.

ops() ->
    ?LET(Ops, non_empty(list(frequency([{6, write_op()}, {2, delete_op()}, {1, gc_op()}]))), times(Ops, #{}, 0)).

%% (now and then a long write: long windows to scan)
write_op() ->
    ?LET({Owner, N}, {oneof([a, b, c, d]), range(1, 3)},
         {write, Owner, [{body(), vec(-1.0, 1.0), vec(-400.0, 400.0)} || _ <- lists:seq(1, N)],
          frequency([{9, range(1, 12)}, {1, range(40, 200)}])}).

delete_op() -> {delete, oneof([a, b, c, d]), range(0, 6)}.

gc_op() -> {gc, range(0, 6)}.

body() -> range(0, 2).

vec(Lo, Hi) -> {float(Lo, Hi), float(Lo, Hi), float(Lo, Hi)}.

%% Times that run forward per writer, as an entity's writes do: a write
%% starts where the writer's last one ended (or earlier, after a delete);
%% deletes and sweeps are given offsets from the present. Each writer's
%% bodies get their own idx (Owner's rank * 3 + the body).
times([], _Ends, _Now) -> [];
times([{write, Owner, Bodies, Substeps} | Rest], Ends, Now) ->
    T0 = maps:get(Owner, Ends, 0),
    Rank = rank(Owner),
    Own = lists:ukeysort(1, [{Rank * 3 + B, P, V} || {B, P, V} <- Bodies]),
    End = T0 + Substeps * ?DT,
    [{write, Owner, T0, Own, Substeps} | times(Rest, Ends#{Owner => End}, max(Now, End))];
times([{delete, Owner, Back} | Rest], Ends, Now) ->
    R = max(0, maps:get(Owner, Ends, 0) - Back * ?DT),
    [{delete, Owner, R} | times(Rest, Ends#{Owner => min(maps:get(Owner, Ends, 0), R + ?DT)}, Now)];
times([{gc, Back} | Rest], Ends, Now) ->
    %% GVT: at most the earliest end of the writers
    Gvt = max(0, lists:min([Now | maps:values(Ends)]) - Back * ?DT),
    [{gc, Gvt} | times(Rest, Ends, Now)].

rank(a) -> 0;
rank(b) -> 1;
rank(c) -> 2;
rank(d) -> 3.
