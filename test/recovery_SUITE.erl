%% Faults cost nothing: a property kills random processes of running
%% simulations (any body, bucket, the GVT process, the table owner, the
%% watchdog) at random times, several times per run, and checks that the
%% frames equal the reference's bit for bit and that nothing of the
%% simulation is left behind; past the restart budget the caller hears
%% {crashed, Who, Reason} within a second.
-module(recovery_SUITE).
-include_lib("proper/include/proper.hrl").
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").
-include("rw_test.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([random_kills_change_no_frame/1, two_kills_at_once/1, past_the_budget_crashes_promptly/1,
         api_after_crash_and_stop/1, schedulers_are_lent_not_taken/1, refused_start_reports_no_crash/1,
         unread_frames_keep_whole_checkpoints/1]).
%% logger handler (refused_start_reports_no_crash)
-export([log/2]).

suite() -> [{timetrap, {minutes, 10}}].

all() -> [random_kills_change_no_frame, two_kills_at_once, past_the_budget_crashes_promptly, api_after_crash_and_stop,
          schedulers_are_lent_not_taken, refused_start_reports_no_crash, unread_frames_keep_whole_checkpoints].

%% Contact-heavy scenes, each over a part where contacts go on all along,
%% and long enough (0.1-0.2 s of wall time on two cores) for the kills,
%% 0-60 ms apart, to land while it runs.
-define(SCENES, [{"bouncing_50_250", scenario, 4000}, {"pile_40", test, 1200}, {"rain_on_logs", test, 800},
                 {"cylinders_200", scenario, 700}]).

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    logger:set_application_level(rigidwarp, error),
    Scenes = rw_test_lib:scenes_with_reference(?SCENES),
    [{scenes, maps:from_list(Scenes)} | Config].

end_per_suite(_Config) ->
    logger:unset_application_level(rigidwarp),
    ok.

drain(Tag) -> receive {Tag, F} -> [F | drain(Tag)] after 0 -> [] end.

%%% Properties

kill() -> {range(0, 60), oneof([body, body, bucket, gvt, tables, watchdog]), pos_integer()}.

random_kills_change_no_frame(Config) ->
    Scenes = ?config(scenes, Config),
    Tally = ets:new(tally, [public]),
    ets:insert(Tally, [{kills, 0}, {restarts, 0}, {runs, 0}]),
    Prop = ?FORALL({Name, Kills, CheckpointMs}, {oneof(maps:keys(Scenes)), [kill(), kill() | list(kill())], range(5, 200)},
                   begin
                       {Scene, Reference} = maps:get(Name, Scenes),
                       {Result, Frames, Done} = run_with_kills(Scene, lists:sublist(Kills, 4), CheckpointMs),
                       Restarts = case Result of {ok, #{restarts := R}} -> R; _ -> -1 end,
                       ets:update_counter(Tally, kills, Done),
                       ets:update_counter(Tally, restarts, max(0, Restarts)),
                       ets:update_counter(Tally, runs, 1),
                       ?WHENFAIL(ct:pal("~s, checkpoints every ~b ms, kills ~p (~b done): ~P~nfirst difference: ~p",
                                        [Name, CheckpointMs, Kills, Done, Result, 8,
                                         rw_test_lib:first_difference(Reference, Frames)]),
                                 aggregate([list_to_atom(Name)],
                                           conjunction([{ok, element(1, Result) =:= ok},
                                                        %% two kills close together can land in one
                                                        %% tree: one restart answers both
                                                        {restarted, Done =:= 0 orelse Restarts >= 1},
                                                        {frames, rw_test_lib:bitwise_equal(Reference, Frames)},
                                                        {no_leak, no_leak()}])))
                   end),
    true = proper:quickcheck(Prop, [{numtests, 30}, {to_file, user}, long_result]),
    [{_, Kills}] = ets:lookup(Tally, kills),
    [{_, Restarts}] = ets:lookup(Tally, restarts),
    [{_, Runs}] = ets:lookup(Tally, runs),
    io:format(user, "fault injection: ~b kills survived in ~b runs (~b restarts)~n", [Kills, Runs, Restarts]),
    %% 2-4 kills are planned per run, at random times: some land after a
    %% short run has ended (seen: 106 to 112 landed in 30 runs)
    ?assert(2 * Kills >= 3 * Runs),
    {comment, io_lib:format("~b kills survived in ~b runs (~b restarts)", [Kills, Runs, Restarts])}.

%% Run Scene while a killer kills, at each {DelayMs, Kind, Pick} (delays
%% after the previous kill), a process of that kind of the simulation's
%% current tree: the run's result, its frames and how many kills landed.
run_with_kills(Scene, Kills, CheckpointMs) ->
    Self = self(),
    Before = [P || {_, P, _, _} <- supervisor:which_children(rw_sims_sup)],
    Killer = spawn_link(fun() -> killer(Self, Before, Kills, 0) end),
    Result = rw_timewarp:run(Scene, #{on_frame => fun(F) -> Self ! {frame, F} end, checkpoint_ms => CheckpointMs,
                                      max_restarts => 100}),
    Killer ! stop,
    Done = receive {killed, N} -> N end,
    {Result, drain(frame), Done}.

killer(Parent, _Before, [], N) ->
    receive stop -> Parent ! {killed, N} end;
killer(Parent, Before, [{Delay, Kind, Pick} | Rest], N) ->
    receive
        stop -> Parent ! {killed, N}
    after Delay ->
            Victims = case [P || {_, P, _, _} <- supervisor:which_children(rw_sims_sup)] -- Before of
                          [Run] -> [P || {P, Who} <- processes(Run), kind(Who) =:= Kind];
                          _ -> []
                      end,
            case Victims of
                [] ->
                    killer(Parent, Before, Rest, N);
                _ ->
                    exit(lists:nth(1 + Pick rem length(Victims), Victims), kill),
                    killer(Parent, Before, Rest, N + 1)
            end
    end.

processes(Run) ->
    try rw_run:processes(Run) catch exit:_ -> [] end.

kind({body, _}) -> body;
kind({bucket, _}) -> bucket;
kind(Who) -> Who.

%% Nothing of a run is left: no simulation, no process, no table.
no_leak() ->
    no_leak(20).

no_leak(0) -> false;
no_leak(Tries) ->
    case supervisor:which_children(rw_sims_sup) =:= [] andalso
        lists:all(fun(T) -> ets:info(T, name) =/= rw_records andalso ets:info(T, name) =/= rw_frames end, ets:all()) of
        true -> true;
        false -> timer:sleep(50), no_leak(Tries - 1)
    end.

%% A run whose frames nobody reads keeps its bodies' records whole only
%% where the engine reads them (rw_commits:commit/4): without gravity,
%% records only there (Bouncing); under gravity, where the regroup plan
%% reads every body's motion, slim records elsewhere (a pile). Every
%% checkpoint, announced a stride ahead, still holds every body's whole
%% state, bit for bit the reference's at that time, while processes are
%% killed and the run restarts from them. (Bouncing takes some 0.1 s of
%% wall time on two cores, so that checkpoints every 0-10 ms come at
%% least twice after a restart from 0.)
unread_frames_keep_whole_checkpoints(_Config) ->
    Self = self(),
    Scenes = [begin
                  {ok, Scene} = rigidwarp:load(Path, #{until => Until}),
                  {ok, _} = rw_reference:run(Scene, #{on_checkpoint => fun(C) -> Self ! {reference, C} end,
                                                      checkpoint_ms => 0}),
                  {Scene, maps:from_list([{T, C} || {checkpoint, T, _, _} = C <- drain(reference)])}
              end || {Path, Until} <- [{rw_test_lib:scenario("bouncing_50_250.json"), 5000},
                                       {rw_test_lib:test_scene("pile_40.json"), 1000}]],
    Prop = ?FORALL({{Scene, Reference}, Kills, CheckpointMs}, {oneof(Scenes), list(kill()), range(0, 10)},
                   begin
                       Before = [P || {_, P, _, _} <- supervisor:which_children(rw_sims_sup)],
                       Killer = spawn_link(fun() -> killer(Self, Before, lists:sublist(Kills, 3), 0) end),
                       Result = rw_timewarp:run(Scene, #{on_checkpoint => fun(C) -> Self ! {checkpoint, C} end,
                                                         checkpoint_ms => CheckpointMs, max_restarts => 100}),
                       Killer ! stop,
                       receive {killed, _} -> ok end,
                       Checkpoints = drain(checkpoint),
                       ?WHENFAIL(ct:pal("~s, checkpoints every ~b ms, kills ~p: ~P~ncheckpoints at ~w",
                                        [Scene#scene.name, CheckpointMs, Kills, Result, 8,
                                         [T || {checkpoint, T, _, _} <- Checkpoints]]),
                                 aggregate([binary_to_atom(Scene#scene.name)],
                                           conjunction([{ok, element(1, Result) =:= ok},
                                                        {some, length(Checkpoints) >= 2},
                                                        {whole, lists:all(fun({checkpoint, T, _, _} = C) ->
                                                                                  rw_test_lib:bitwise_equal(maps:get(T, Reference), C)
                                                                          end, Checkpoints)},
                                                        {no_leak, no_leak()}])))
                   end),
    true = proper:quickcheck(Prop, [{numtests, 24}, {to_file, user}, long_result]).

%%% Examples

%% A shrunk counterexample, kept: two bodies killed one right after the
%% other, checkpoints every 6 ms. The second restart began before the first
%% restarted simulation's frames had reached the ring's latest frame: the
%% ring, writing them again, pushed that later frame out with the records
%% the restarted bodies had just committed at its time, and the GVT process
%% crashed planning groups from them.
two_kills_at_once(Config) ->
    {Scene, Reference} = maps:get("bouncing_50_250", ?config(scenes, Config)),
    [begin
         {Result, Frames, _} = run_with_kills(Scene, [{1, body, 1}, {0, body, 1}], 6),
         ?assertMatch({ok, _}, Result),
         ?assertBitwise(Reference, Frames)
     end || _ <- lists:seq(1, 5)],
    ?assert(no_leak()),
    ok.

%% With no restarts left, any fault ends the run at once: the caller of
%% run/2 and of await/2 gets {crashed, Who, Reason} within a second, stats/1
%% says crashed, and the frames committed so far stay readable until stop.
past_the_budget_crashes_promptly(Config) ->
    {Scene, Reference} = maps:get("bouncing_50_250", ?config(scenes, Config)),
    File = Scene#scene.file,
    {ok, Sim} = rigidwarp:start(File, #{until => 1000, max_restarts => 0}),
    {rw_sim, Run, _} = Sim,
    wait_for_frames(Sim, 200),
    [Gvt | _] = [P || {P, gvt} <- rw_run:processes(Run)],
    T0 = erlang:monotonic_time(millisecond),
    exit(Gvt, kill),
    ?assertEqual({error, {crashed, gvt, killed}}, rigidwarp:await(Sim, 5000)),
    ?assert(erlang:monotonic_time(millisecond) - T0 < 1000),
    ?assertMatch(#{status := crashed}, rigidwarp:stats(Sim)),
    {frame, Last, _} = Latest = rigidwarp:frames(Sim),
    ?assertBitwise(lists:keyfind(Last, 2, Reference), Latest),
    ?assertEqual([], rw_run:processes(Run)),
    ok = rigidwarp:stop(Sim),
    ?assert(no_leak()),
    %% run/2 alike
    Self = self(),
    Kill = fun({frame, 100, _}) ->
                   [R] = [P || {_, P, _, _} <- supervisor:which_children(rw_sims_sup)],
                   [B | _] = [P || {P, {bucket, _}} <- rw_run:processes(R)],
                   Self ! {killed, erlang:monotonic_time(millisecond)},
                   exit(B, kill);
              (_) -> ok
           end,
    {error, {crashed, {bucket, _}, killed}} = rw_timewarp:run(Scene, #{on_frame => Kill, max_restarts => 0}),
    Killed = receive {killed, K} -> K end,
    ?assert(erlang:monotonic_time(millisecond) - Killed < 1000),
    ?assert(no_leak()),
    ok.

wait_for_frames(Sim, Ms) ->
    case rigidwarp:gvt(Sim) of
        G when G >= Ms -> ok;
        _ -> timer:sleep(10), wait_for_frames(Sim, Ms)
    end.

%% Calls on a forged or stopped handle answer {error, _}; start/2 refuses
%% what only run/2 takes; run/2 leaks nothing when its callback raises.
api_after_crash_and_stop(Config) ->
    {Scene, _} = maps:get("bouncing_50_250", ?config(scenes, Config)),
    File = Scene#scene.file,
    {ok, Sim} = rigidwarp:start(File, #{until => 1000}),
    ok = rigidwarp:stop(Sim),
    Stopped = {error, "the simulation has been stopped"},
    [?assertEqual(Stopped, Call()) || Call <- [fun() -> rigidwarp:frames(Sim) end, fun() -> rigidwarp:gvt(Sim) end,
                                               fun() -> rigidwarp:stats(Sim) end, fun() -> rigidwarp:view(Sim) end,
                                               fun() -> rigidwarp:await(Sim, 10) end,
                                               fun() -> rigidwarp:subscribe(Sim) end, fun() -> rigidwarp:stop(Sim) end]],
    Forged = setelement(2, Sim, self()),
    ?assertEqual(Stopped, rigidwarp:frames(Forged)),
    ?assertMatch({error, "not a simulation" ++ _}, rigidwarp:gvt(#{run => self()})),
    ?assert(length(lists:flatten(io_lib:format("~p", [Sim]))) < 80),
    [?assertMatch({error, "start/2 does not take " ++ _}, rigidwarp:start(File, #{K => V}))
     || {K, V} <- [{frames, "x.jsonl"}, {on_frame, fun(_) -> ok end}, {on_progress, fun(_) -> ok end},
                   {resume, true}]],
    Boom = fun({frame, 50, _}) -> error(boom); (_) -> ok end,
    {error, Message} = rigidwarp:run(File, #{until => 1000, on_frame => Boom}),
    ?assertMatch({match, _}, re:run(Message, "boom")),
    ?assertEqual(nomatch, string:find(Message, "\n")),
    ?assert(no_leak()),
    ?assertEqual([], [M || {rw_frame, _, _} = M <- element(2, erlang:process_info(self(), messages))]),
    ok.

%% A run's schedulers are lent by the VM for the run: two overlapping runs
%% with different counts cannot both have them (the second is refused),
%% and the count from before comes back when the run ends. (A runs ten
%% simulated minutes, some seconds of wall time, so that it is still
%% running when B has ended; it is stopped long before its end.)
schedulers_are_lent_not_taken(Config) ->
    {Scene, _} = maps:get("bouncing_50_250", ?config(scenes, Config)),
    File = Scene#scene.file,
    Online = erlang:system_info(schedulers_online),
    {ok, A} = rigidwarp:start(File, #{until => 600000, schedulers => 1}),
    ?assertEqual(1, erlang:system_info(schedulers_online)),
    case erlang:system_info(schedulers) of
        1 -> ok;
        _ -> ?assertMatch({error, "schedulers: another simulation runs with 1 " ++ _},
                          rigidwarp:start(File, #{until => 100, schedulers => 2}))
    end,
    {ok, B} = rigidwarp:start(File, #{until => 100, schedulers => 1}),
    ok = rigidwarp:await(B, 10000),
    ok = rigidwarp:stop(B),
    ?assertEqual(1, erlang:system_info(schedulers_online)),
    ok = rigidwarp:stop(A),
    timer:sleep(50),
    ?assertEqual(Online, erlang:system_info(schedulers_online)),
    ok.

%% A start refused (another run holds another schedulers count) is one
%% line to its caller and nothing else: no crash report, nothing logged
%% at error level, no run left.
refused_start_reports_no_crash(Config) ->
    {Scene, _} = maps:get("bouncing_50_250", ?config(scenes, Config)),
    File = Scene#scene.file,
    case erlang:system_info(schedulers) of
        1 -> {skip, "one scheduler: nothing to refuse"};
        _ ->
            {ok, A} = rigidwarp:start(File, #{until => 600000, schedulers => 1}),
            Runs = supervisor:which_children(rw_sims_sup),
            ok = logger:add_handler(refused_start, ?MODULE, #{level => all, config => #{to => self()}}),
            try
                {error, Message} = rigidwarp:start(File, #{until => 100, schedulers => 2}),
                ?assertMatch("schedulers: another simulation runs with 1 " ++ _, Message),
                ?assertEqual(nomatch, string:find(Message, "\n")),
                timer:sleep(200),
                Logged = [E || {logged, E} <- drain_all()],
                ct:log("logged: ~p", [Logged]),
                ?assertEqual([], [E || #{level := L} = E <- Logged, logger:compare_levels(L, error) =/= lt]),
                ?assertEqual(Runs, supervisor:which_children(rw_sims_sup))
            after
                _ = logger:remove_handler(refused_start),
                ok = rigidwarp:stop(A)
            end
    end.

log(Event, #{config := #{to := Pid}}) -> Pid ! {logged, Event}.

drain_all() -> receive M -> [M | drain_all()] after 0 -> [] end.
