-module(rw_sim_tests).
%% rw_sim:lead/4, the highest LVT that stats show: read anew at most once
%% a second.
-include_lib("eunit/include/eunit.hrl").

%% Bodies 0..3 with LVTs 5, 9, 2, 7 in their slots.
lvts() ->
    Lvts = atomics:new(rw_sim:lvt_slot(3), [{signed, false}]),
    _ = [atomics:put(Lvts, rw_sim:lvt_slot(I), T) || {I, T} <- [{0, 5}, {1, 9}, {2, 2}, {3, 7}]],
    Lvts.

first_read_is_the_highest_test() ->
    Lvts = lvts(),
    ?assertEqual({9, {100, 9}}, rw_sim:lead(Lvts, all, 100, none)),
    ?assertEqual({7, {100, 7}}, rw_sim:lead(Lvts, [0, 2, 3], 100, none)).

a_read_holds_for_a_second_test() ->
    Lvts = lvts(),
    {9, Read} = rw_sim:lead(Lvts, all, 100, none),
    ok = atomics:put(Lvts, rw_sim:lvt_slot(2), 40),
    ?assertEqual({9, Read}, rw_sim:lead(Lvts, all, 1099, Read)),
    ?assertEqual({40, {1100, 40}}, rw_sim:lead(Lvts, all, 1100, Read)).

a_body_elsewhere_is_not_read_test() ->
    Lvts = lvts(),
    ?assertEqual({5, {0, 5}}, rw_sim:lead(Lvts, [0, 2], 0, none)),
    ?assertEqual({0, {0, 0}}, rw_sim:lead(Lvts, [], 0, none)).
