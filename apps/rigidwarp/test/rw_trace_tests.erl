%% The tracer's cost of a task: its reductions, plus the time its C loops
%% (rw_native) took at the rate of the engine's Erlang code, which the
%% reductions alone would miss (a call into C counts as one).
-module(rw_trace_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").

%% Time between native_begin/0 and native_end/1 is counted.
native_time_is_counted_test() ->
    [{_, _, body, Cost, _, _, _}] = traced(fun() ->
                                               ok = rw_trace:native_begin(),
                                               ok = rw_trace:native_end(timer:sleep(20))
                                           end),
    %% 20 ms at 25 reductions per microsecond
    ?assert(Cost >= 500000).

%% A task that calls a C loop (a group's substeps, rw_native:island_run/10)
%% counts its time: far more than its reductions.
c_loops_are_timed_test() ->
    ?assert(rw_native:enabled()),
    M = #model{gravity = {0.0, -9.81, 0.0}, rotation = true, friction = 0.3},
    Spheres = [#sphere{idx = I, id = integer_to_binary(I), radius = 0.1, mass = 1.0, inv_mass = 1.0,
                       inv_inertia = 250.0} || I <- lists:seq(1, 32)],
    States = list_to_tuple([#st{p = {0.19 * (I rem 8), 0.1 + 0.19 * (I div 8), 0.0}, v = {0.0, 0.0, 0.0},
                                q = rw_quat:identity(), w = {0.0, 0.0, 0.0}} || I <- lists:seq(1, 32)]),
    Floor = rw_shape:fixture(0, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0}),
    Run = fun() -> rw_native:island_run(0, 100, 1, M, list_to_tuple(Spheres), [Floor], States, none, [], []) end,
    {T1, _, _, none, []} = Run(),
    ?assert(T1 > 0),
    %% (the reductions of the call's own Erlang code, the call's share of
    %% its time slice excluded)
    [{_, _, body, Cost, _, _, _}] = traced(Run),
    [{_, _, body, Erlang, _, _, _}] = traced(fun() -> rw_native:use(false), rw_native:enabled() end),
    ?assert(Cost > 10 * Erlang).

%% Fun as one traced task of a process of its own (the tracer keeps its
%% state in the process dictionary).
traced(Fun) ->
    Tab = ets:new(trace, [public, duplicate_bag]),
    Self = self(),
    {Pid, Ref} = spawn_monitor(fun() ->
                                       ok = rw_trace:init(Tab),
                                       ok = rw_trace:begin_task(body, none),
                                       _ = Fun(),
                                       ok = rw_trace:end_task(),
                                       Self ! {self(), done}
                               end),
    receive {Pid, done} -> ok end,
    receive {'DOWN', Ref, process, Pid, normal} -> ok end,
    Tasks = ets:tab2list(Tab),
    ets:delete(Tab),
    Tasks.
