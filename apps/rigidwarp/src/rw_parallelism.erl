%% How parallel a run's work is (pure): from the tasks a traced run
%% recorded (rw_trace), the graph of their dependencies, its total work,
%% its critical path and the speedup a list schedule of it gets on P cores.
%%
%% A task depends on
%%   - the task its process ran before it (a process runs one task at a time);
%%   - the task that sent each message it took in (an event, an
%%     acknowledgement, an antievent, a bucket's answer, which a bucket sends
%%     when it grants the lock asked for, a GVT wake-up, a regroup move);
%%   - for the GVT process advancing GVT to G: every task that committed a
%%     sync point up to G since its last advance (GVT waits for all of them,
%%     though only the last one tells it).
%% Costs are reductions, the VM's unit of work. The list schedule takes the
%% tasks in the order they become ready (the earliest ready first, ties in
%% the order they ran) onto the core that is free first; a process is never
%% on two cores, since its tasks depend on each other. It assumes that the
%% same work would be done on P cores: Time Warp on more cores computes
%% optimistically further and rolls back more, which it does not see.
-module(rw_parallelism).
-export([analyze/2]).
-export_type([summary/0]).

-type summary() :: #{tasks := non_neg_integer(), work := non_neg_integer(), critical_path := non_neg_integer(),
                     parallelism := float(), speedup := #{pos_integer() => float()},
                     critical_by_kind := #{atom() => float()}}.

%% The summary of Tasks (rw_trace:task(), in any order), with the list
%% schedule's speedup on each of Cores.
-spec analyze([rw_trace:task()], [pos_integer()]) -> summary().
analyze(Tasks, Cores) ->
    {Costs, Kinds, Deps} = graph(Tasks),
    Work = lists:sum(tuple_to_list(Costs)),
    {Path, ByKind} = critical({Costs, Kinds, Deps}),
    #{tasks => tuple_size(Costs), work => Work, critical_path => Path,
      parallelism => Work / max(1, Path),
      speedup => maps:from_list([{P, Work / max(1, schedule({Costs, Deps}, P))} || P <- Cores]),
      critical_by_kind => maps:map(fun(_, C) -> C / max(1, Path) end, ByKind)}.

%% The graph: tasks numbered 1..N in the order they began, each with its
%% cost, its kind and the tasks it depends on (all numbered lower).
graph(Tasks0) ->
    Tasks = lists:keysort(1, Tasks0),
    {_, _, _, _, Rev} =
        lists:foldl(
          fun({_Seq, Pid, Kind, Cost, In, Out, Commits}, {K, LastOf, Sender, Committed, Acc}) ->
                  Own = case LastOf of #{Pid := Prev} -> [Prev]; _ -> [] end,
                  Msgs = [S || Key <- In, {ok, S} <- [maps:find(Key, Sender)]],
                  {Gvt, Committed1} = case {Kind, Commits} of
                                          {_, []} -> {[], Committed};
                                          {gvt, [G | _]} ->
                                              {Up, Later} = lists:partition(fun({T, _}) -> T =< G end, Committed),
                                              {[C || {_, C} <- Up], Later};
                                          _ -> {[], [{T, K} || T <- Commits] ++ Committed}
                                      end,
                  Deps = lists:usort(Own ++ Msgs ++ Gvt),
                  Sender1 = lists:foldl(fun(Key, M) -> M#{Key => K} end, Sender, Out),
                  {K + 1, LastOf#{Pid => K}, Sender1, Committed1, [{Cost, Kind, Deps} | Acc]}
          end, {1, #{}, #{}, [], []}, Tasks),
    Nodes = lists:reverse(Rev),
    {list_to_tuple([C || {C, _, _} <- Nodes]), list_to_tuple([Kd || {_, Kd, _} <- Nodes]),
     list_to_tuple([D || {_, _, D} <- Nodes])}.

%% The longest path through the graph (by cost) and how its cost divides
%% among the kinds of task on it.
-spec critical({tuple(), tuple(), tuple()}) -> {non_neg_integer(), #{atom() => non_neg_integer()}}.
critical({Costs, Kinds, Deps}) ->
    N = tuple_size(Costs),
    %% per task: the longest path ending with it, and the dependency on it
    Longest = lists:foldl(
                fun(K, Acc) ->
                        {Best, Via} = lists:foldl(fun(D, {B, V}) ->
                                                          case element(1, maps:get(D, Acc)) of
                                                              L when L > B -> {L, D};
                                                              _ -> {B, V}
                                                          end
                                                  end, {0, none}, element(K, Deps)),
                        Acc#{K => {Best + element(K, Costs), Via}}
                end, #{}, lists:seq(1, N)),
    case N of
        0 -> {0, #{}};
        _ ->
            {Path, Last} = lists:max([{L, K} || {K, {L, _}} <- maps:to_list(Longest)]),
            {Path, by_kind(Last, Longest, Costs, Kinds, #{})}
    end.

by_kind(none, _Longest, _Costs, _Kinds, Acc) -> Acc;
by_kind(K, Longest, Costs, Kinds, Acc) ->
    {_, Via} = maps:get(K, Longest),
    by_kind(Via, Longest, Costs, Kinds, maps:update_with(element(K, Kinds), fun(C) -> C + element(K, Costs) end,
                                                        element(K, Costs), Acc)).

%% The makespan of a list schedule of the graph on P cores.
-spec schedule({tuple(), tuple()}, pos_integer()) -> non_neg_integer().
schedule({Costs, Deps}, P) ->
    N = tuple_size(Costs),
    Succ = lists:foldl(fun(K, Acc) ->
                               lists:foldl(fun(D, A) -> maps:update_with(D, fun(L) -> [K | L] end, [K], A) end,
                                           Acc, element(K, Deps))
                       end, #{}, lists:seq(1, N)),
    Waiting = maps:from_list([{K, length(element(K, Deps))} || K <- lists:seq(1, N)]),
    Ready = gb_sets:from_list([{0, K} || K <- lists:seq(1, N), element(K, Deps) =:= []]),
    Cores = gb_sets:from_list([{0, C} || C <- lists:seq(1, P)]),
    run(Ready, Cores, Waiting, #{}, Succ, Costs, 0).

run(Ready, Cores, Waiting, ReadyAt, Succ, Costs, Makespan) ->
    case gb_sets:is_empty(Ready) of
        true -> Makespan;
        false ->
            {{At, K}, Ready1} = gb_sets:take_smallest(Ready),
            {{Free, C}, Cores1} = gb_sets:take_smallest(Cores),
            Finish = max(At, Free) + element(K, Costs),
            {Ready2, Waiting1, ReadyAt1} =
                lists:foldl(fun(S, {R, W, RA}) ->
                                    T = max(Finish, maps:get(S, RA, 0)),
                                    case maps:get(S, W) - 1 of
                                        0 -> {gb_sets:add({T, S}, R), maps:remove(S, W), maps:remove(S, RA)};
                                        Left -> {R, W#{S := Left}, RA#{S => T}}
                                    end
                            end, {Ready1, Waiting, ReadyAt}, maps:get(K, Succ, [])),
            run(Ready2, gb_sets:add({Finish, C}, Cores1), Waiting1, ReadyAt1, Succ, Costs, max(Makespan, Finish))
    end.
