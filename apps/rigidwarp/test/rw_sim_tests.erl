-module(rw_sim_tests).
%% rw_sim:lead/4, the highest LVT that stats show: read anew once the last
%% read is a millisecond old per 20 bodies.
-include_lib("eunit/include/eunit.hrl").

%% Bodies 0..N-1, body I at LVT I + 1 but body 2 at 10 * N.
lvts(N) ->
    Lvts = atomics:new(rw_sim:lvt_slot(N - 1), [{signed, false}]),
    _ = [atomics:put(Lvts, rw_sim:lvt_slot(I), I + 1) || I <- lists:seq(0, N - 1)],
    ok = atomics:put(Lvts, rw_sim:lvt_slot(2), 10 * N),
    Lvts.

first_read_is_the_highest_test() ->
    Lvts = lvts(4),
    ?assertEqual({40, {100, 40}}, rw_sim:lead(Lvts, all, 100, none)),
    ?assertEqual({4, {100, 4}}, rw_sim:lead(Lvts, [0, 1, 3], 100, none)),
    ?assertEqual({0, {100, 0}}, rw_sim:lead(Lvts, [], 100, none)).

%% 20,000 bodies: a read holds for a second.
a_read_of_many_holds_for_a_while_test() ->
    Lvts = lvts(20000),
    {200000, Read} = rw_sim:lead(Lvts, all, 100, none),
    ok = atomics:put(Lvts, rw_sim:lvt_slot(7), 300000),
    ?assertEqual({200000, Read}, rw_sim:lead(Lvts, all, 1099, Read)),
    ?assertEqual({300000, {1100, 300000}}, rw_sim:lead(Lvts, all, 1100, Read)),
    %% a site's 2,000 of them: a tenth of a second
    Some = lists:seq(0, 1999),
    {300000, Read2} = rw_sim:lead(Lvts, Some, 100, none),
    ok = atomics:put(Lvts, rw_sim:lvt_slot(9), 400000),
    ?assertEqual({300000, Read2}, rw_sim:lead(Lvts, Some, 199, Read2)),
    ?assertEqual({400000, {200, 400000}}, rw_sim:lead(Lvts, Some, 200, Read2)).

%% A few bodies are read at every call.
a_read_of_few_is_always_fresh_test() ->
    Lvts = lvts(19),
    {190, Read} = rw_sim:lead(Lvts, all, 100, none),
    ok = atomics:put(Lvts, rw_sim:lvt_slot(5), 500),
    ?assertEqual({500, {100, 500}}, rw_sim:lead(Lvts, all, 100, Read)).
