%% A committed record gives back, bit for bit, the frame record and the
%% pre-response velocities it was made from, with and without rotation,
%% with and without a response at its time (-0.0 is not 0.0).
-module(rw_commits_tests).
-include_lib("eunit/include/eunit.hrl").
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include_lib("rigidwarp/include/rigidwarp.hrl").

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

%% With sparse records a commit counts every member but keeps the records
%% only where the engine reads them: where the entity says the regroup plan
%% may, at the announced checkpoint's sync point and at the end; a run whose
%% frames someone reads keeps them all.
sparse_commits_test() ->
    Sim = commits_sim(sparse),
    ok = rw_commits:checkpoint_at(Sim, 30),
    Row = fun(T, I) -> rw_commits:record(T, I, integer_to_binary(I), {1.0, 2.0, 3.0}, {0.0, 0.0, 0.0}, undefined, undefined,
                                         {{0.0, 0.0, 0.0}, undefined}) end,
    Commit = fun(T, Planned) -> ok = rw_commits:commit(Sim, T, [Row(T, 1), Row(T, 2)], Planned) end,
    Commit(10, false),
    Commit(20, true),
    Commit(30, false),
    Commit(40, false),
    Commit(50, false),
    ?assertEqual([0, 2, 2, 0, 2], [length(rw_commits:select_at(T, Sim#sim.records)) || T <- [10, 20, 30, 40, 50]]),
    ?assertEqual([{2, 0} || _ <- [10, 20, 30, 40, 50]], [rw_commits:count(Sim, T) || T <- [10, 20, 30, 40, 50]]),
    %% kept after all, once the plan is to read them
    ok = rw_commits:keep(Sim, [Row(40, 1)]),
    ?assertMatch([{<<"1">>, _, _, _, _}], rw_commits:select_at(40, Sim#sim.records)),
    Every = commits_sim(whole),
    _ = [ok = rw_commits:commit(Every, T, [Row(T, 1)], false) || T <- [10, 20]],
    ?assertEqual([1, 1], [length(rw_commits:select_at(T, Every#sim.records)) || T <- [10, 20]]).

%% With slim records a commit keeps every member's record, whole at the
%% announced checkpoint's sync point and at the end, elsewhere only the
%% motion the regroup plan reads: bit for bit that of the whole record,
%% with and without rotation, and never taken for a frame.
slim_commits_test() ->
    Sim = commits_sim(slim),
    ok = rw_commits:checkpoint_at(Sim, 30),
    Row = fun(T, 1) -> rw_commits:record(T, 1, <<"1">>, {1.0, -0.0, 3.0e300}, {0.0, -2.5, 1.0e-300}, undefined, undefined,
                                         {{0.0, 2.5, 1.0e-300}, undefined});
             (T, 2) -> rw_commits:record(T, 2, <<"2">>, {-0.0, 2.0, 3.0}, {-0.0, 0.5, 7.0}, {{0.5, -0.5, 0.5}, -0.5},
                                         {0.0, -3.25, 7.0}, {{1.0, 0.5, 7.0}, {0.0, 0.0, 7.0}})
          end,
    _ = [ok = rw_commits:commit(Sim, T, [Row(T, 1), Row(T, 2)], false) || T <- [10, 30, 50]],
    Records = Sim#sim.records,
    Motions = [{1, {1.0, -0.0, 3.0e300}, {0.0, -2.5, 1.0e-300}}, {2, {-0.0, 2.0, 3.0}, {-0.0, 0.5, 7.0}}],
    _ = [?assertBitwise(Motions, rw_commits:motions_at(T, all, Records)) || T <- [10, 30, 50]],
    ?assertBitwise(Motions, rw_commits:motions_at(10, [1, 2], Records)),
    ?assertEqual([[], 2, 2], [case rw_commits:select_at(T, Records) of [] -> []; L -> length(L) end || T <- [10, 30, 50]]),
    %% (49 bytes: a heap binary)
    ?assertEqual([49, 49], [byte_size(Bin) || {_, _, Bin} <- ets:lookup(Records, {10, 1}) ++ ets:lookup(Records, {10, 2})]),
    ?assertBitwise([rw_commits:unpack(Row(30, I)) || I <- [1, 2]], [rw_commits:unpack(R) || R <- ets:tab2list(Records),
                                                                                           element(1, element(1, R)) =:= 30]),
    ?assertEqual([{2, 0} || _ <- [10, 30, 50]], [rw_commits:count(Sim, T) || T <- [10, 30, 50]]).

commits_sim(Kept) ->
    Now = atomics:new(2, [{signed, true}]),
    #sim{records = ets:new(records, [ordered_set, public]), counts = ets:new(counts, [set, public]), n = 3, end_t = 50,
         gvt = self(), gvt_now = Now, records_kept = Kept}.
