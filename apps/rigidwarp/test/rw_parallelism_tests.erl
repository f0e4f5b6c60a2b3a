%% The parallelism projection on small task graphs whose answer is known.
-module(rw_parallelism_tests).
-include_lib("eunit/include/eunit.hrl").

%% {Seq, Process, Kind, Cost, TakenIn, Sent, Committed}
task(Seq, Proc, Cost) -> task(Seq, Proc, body, Cost, [], [], []).
task(Seq, Proc, Kind, Cost, In, Out, Commits) -> {Seq, pid(Proc), Kind, Cost, In, Out, Commits}.

pid(N) -> list_to_pid("<0." ++ integer_to_list(100 + N) ++ ".0>").

key(To, Msg) -> rw_trace:key(pid(To), Msg).

one_process_is_serial_test() ->
    S = rw_parallelism:analyze([task(1, 1, 10), task(2, 1, 20), task(3, 1, 30)], [2, 8]),
    ?assertMatch(#{work := 60, critical_path := 60, tasks := 3}, S),
    ?assertEqual(#{2 => 1.0, 8 => 1.0}, maps:get(speedup, S)).

independent_processes_spread_test() ->
    Tasks = [task(K, K, 10) || K <- lists:seq(1, 8)],
    #{work := 80, critical_path := 10, parallelism := Par, speedup := Speedup} =
        rw_parallelism:analyze(Tasks, [1, 2, 4, 8, 64]),
    ?assertEqual(8.0, Par),
    ?assertEqual(#{1 => 1.0, 2 => 2.0, 4 => 4.0, 8 => 8.0, 64 => 8.0}, Speedup).

%% A message makes its receiver's task wait for its sender's: a process's
%% two tasks after another's first are a chain of three.
message_orders_tasks_test() ->
    Msg = {event, x},
    Tasks = [task(1, 1, body, 10, [], [key(2, Msg)], []),
             task(2, 2, body, 10, [key(2, Msg)], [], []),
             task(3, 2, body, 10, [], [], []),
             task(4, 1, body, 10, [], [], [])],
    ?assertMatch(#{critical_path := 30, work := 40}, rw_parallelism:analyze(Tasks, [2])),
    %% without the message each process's chain is 20
    Apart = [setelement(5, setelement(6, T, []), []) || T <- Tasks],
    ?assertMatch(#{critical_path := 20, speedup := #{2 := 2.0}}, rw_parallelism:analyze(Apart, [2])).

%% The message a task takes in is the last one sent before it under its key.
last_sender_counts_test() ->
    Msg = {gvt, 5},
    Tasks = [task(1, 1, gvt, 5, [], [key(3, Msg)], []),
             task(2, 2, body, 50, [], [], []),
             task(3, 2, gvt, 5, [], [key(3, Msg)], []),
             task(4, 3, body, 10, [key(3, Msg)], [], [])],
    %% 4 waits for 3, which waits for 2: 50 + 5 + 10
    ?assertMatch(#{critical_path := 65}, rw_parallelism:analyze(Tasks, [2])).

%% GVT reaching G waits for every commit up to G, not only for the last
%% committer that told it; commits after G are not waited for.
gvt_waits_for_every_commit_test() ->
    Slow = task(1, 1, body, 100, [], [], [10]),
    Quick = task(2, 2, body, 10, [], [], [10]),
    Ahead = task(3, 4, body, 500, [], [], [20]),
    To10 = task(4, 3, gvt, 1, [], [], [10]),
    To20 = task(5, 3, gvt, 1, [], [], [20]),
    ?assertMatch(#{critical_path := 101, critical_by_kind := #{body := 0.9900990099009901}},
                 rw_parallelism:analyze([Slow, Quick, To10], [2])),
    ?assertMatch(#{critical_path := 500, critical_by_kind := #{body := 1.0}},
                 rw_parallelism:analyze([Slow, Ahead, To10], [2])),
    ?assertMatch(#{critical_path := 501}, rw_parallelism:analyze([Slow, Ahead, To10, To20], [2])).

%% The list schedule is never better than the work spread evenly or the
%% critical path, and never worse than one core.
schedule_bounds_test() ->
    rand:seed(exsss, 11),
    lists:foreach(
      fun(_) ->
              N = 5 + rand:uniform(60),
              Tasks = [task(K, rand:uniform(6), body, rand:uniform(100), [key(0, {m, rand:uniform(K)})],
                            [key(0, {m, K})], []) || K <- lists:seq(1, N)],
              #{work := Work, critical_path := Path, speedup := Speedup} = rw_parallelism:analyze(Tasks, [1, 2, 3, 8]),
              ?assert(Path =< Work),
              ?assertEqual(1.0, maps:get(1, Speedup)),
              [begin
                   ?assert(S =< P + 1.0e-9),
                   ?assert(S =< Work / Path + 1.0e-9),
                   ?assert(S >= 1.0 - 1.0e-9)
               end || {P, S} <- maps:to_list(Speedup)]
      end, lists:seq(1, 200)).
