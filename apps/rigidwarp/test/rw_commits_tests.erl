%% A committed record gives back, bit for bit, the frame record and the
%% pre-response velocities it was made from, with and without rotation,
%% with and without a response at its time (-0.0 is not 0.0).
-module(rw_commits_tests).
-include_lib("eunit/include/eunit.hrl").
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).

round_trip(P, V, Q, W, Pre) ->
    Record = rw_commits:record(30, 7, <<"b7">>, P, V, Q, W, Pre),
    ?assertBitwise({{<<"b7">>, P, V, Q, W}, Pre}, rw_commits:unpack(Record)),
    ?assertMatch({{30, 7}, _, _}, Record).

without_rotation_test() ->
    V = {1.5, -0.0, 2.0e-300},
    round_trip({0.1, -2.5, 1.0e300}, V, undefined, undefined, {V, undefined}),
    %% after a response: the velocities before it differ
    round_trip({0.1, -2.5, 3.0}, V, undefined, undefined, {{-1.5, 0.0, 2.0e-300}, undefined}),
    %% only in the sign of a zero
    round_trip({0.1, -2.5, 3.0}, {0.0, 1.0, 1.0}, undefined, undefined, {{-0.0, 1.0, 1.0}, undefined}).

with_rotation_test() ->
    V = {1.5, -0.0, 2.0},
    W = {0.0, -3.25, 7.0},
    Q = {{0.5, -0.5, 0.5}, -0.5},
    round_trip({4.0, 5.0, -6.0}, V, Q, W, {V, W}),
    round_trip({4.0, 5.0, -6.0}, V, Q, W, {V, {0.0, -3.25, 7.5}}),
    round_trip({4.0, 5.0, -6.0}, V, Q, W, {{1.5, 0.0, 2.0}, W}).

motions_and_frames_at_test() ->
    Records = ets:new(records, [ordered_set, public]),
    Rows = [rw_commits:record(T, I, integer_to_binary(I), {float(I), float(T), -0.0}, {1.0, 2.0, float(I)},
                              undefined, undefined, {{0.0, 0.0, 0.0}, undefined}) || T <- [10, 20], I <- [3, 1, 2]],
    true = ets:insert(Records, Rows),
    ?assertBitwise([{I, {float(I), 20.0, -0.0}, {1.0, 2.0, float(I)}} || I <- [1, 2, 3]], rw_commits:motions_at(20, all, Records)),
    ?assertBitwise([{I, {float(I), 10.0, -0.0}, {1.0, 2.0, float(I)}} || I <- [1, 3]], rw_commits:motions_at(10, [1, 3, 4], Records)),
    ?assertBitwise([{integer_to_binary(I), {float(I), 10.0, -0.0}, {1.0, 2.0, float(I)}, undefined, undefined} || I <- [1, 2, 3]],
         rw_commits:select_at(10, Records)),
    %% with rotation: only the position and the velocity
    true = ets:insert(Records, [rw_commits:record(30, I, integer_to_binary(I), {float(I), 30.0, -0.0}, {-0.0, 2.0, float(I)},
                                                  {{0.5, -0.5, 0.5}, -0.5}, {0.0, 1.0, 2.0}, {{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}})
                                || I <- [2, 1]]),
    ?assertBitwise([{I, {float(I), 30.0, -0.0}, {-0.0, 2.0, float(I)}} || I <- [1, 2]], rw_commits:motions_at(30, all, Records)),
    ?assertBitwise([{2, {2.0, 30.0, -0.0}, {-0.0, 2.0, 2.0}}], rw_commits:motions_at(30, [2], Records)),
    ok = rw_commits:delete_at(10, Records),
    ?assertEqual([], rw_commits:select_at(10, Records)),
    ?assertEqual(3, length(rw_commits:select_at(20, Records))).
