%% The neighbour rule: a partner touched twice within a few substeps limits
%% an entity to one substep past it; a single touch (a bounce) does not.
-module(rw_neighbour_tests).
-include_lib("eunit/include/eunit.hrl").

touches(Pairs) ->
    lists:foldl(fun({Idx, PIdx, T}, Tch) -> element(1, rw_neighbour:touch(Idx, PIdx, T, Tch)) end,
                rw_neighbour:new(), Pairs).

single_touch_is_a_bounce_test() ->
    ?assertEqual([], rw_neighbour:partners(10, 1, touches([{0, 5, 9}]))).

persistent_contact_test() ->
    Touched = touches([{0, 5, 8}, {0, 5, 9}, {0, 7, 2}, {0, 7, 3}]),
    %% 7's touches are more than 8 substeps before LVT 12
    ?assertEqual([5], rw_neighbour:partners(12, 1, Touched)),
    ?assertEqual([5, 7], lists:sort(rw_neighbour:partners(9, 1, Touched))),
    %% touches at most 8 substeps apart count
    ?assertEqual([], rw_neighbour:partners(12, 1, touches([{0, 5, 1}, {0, 5, 11}]))).

limit_test() ->
    ?assertEqual(none, rw_neighbour:limit([], 1)),
    %% the slowest partner, the lowest idx on a tie, one substep past it
    ?assertEqual({13, 4}, rw_neighbour:limit([{9, 15}, {4, 12}, {6, 12}], 1)).

met_every_fourth_touch_test() ->
    {Reports, _} = lists:mapfoldl(fun(T, Tch) ->
                                          {Tch1, Met} = rw_neighbour:touch(3, 1, T, Tch),
                                          {Met, Tch1}
                                  end, rw_neighbour:new(), lists:seq(1, 9)),
    ?assertEqual([none, none, none, {1, 3, 4}, none, none, none, {1, 3, 8}, none], Reports),
    %% a touch again at a substep already counted is not counted twice
    {_, none} = rw_neighbour:touch(3, 1, 2, touches([{3, 1, 2}])).

forget_test() ->
    Touched = touches([{0, 5, 1}, {0, 6, 20}]),
    ?assertEqual([6], maps:keys(rw_neighbour:forget(20, 1, Touched))).
