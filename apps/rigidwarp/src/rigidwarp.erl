%% @doc The shell API of rigidwarp: validate a scene, run it to its end on
%% the parallel Time Warp engine (the default) or on the sequential
%% reference engine, or start a Time Warp run in the background and read
%% its committed frames, counters and live 3D view while it goes on.
%%
%% Scenes are JSON files ({@link rw_scene} describes them). A frame is
%% `{frame, T, Bodies}': T in ms and, for each dynamic body sorted by id,
%% `{Id, Position, Velocity, Orientation, AngularVelocity}', the last two
%% `undefined' without rotation. Files of frames are JSON Lines
%% ({@link rw_frames}). Options are a map with times in ms
%% ({@link run_options()}); `rigidwarp:help()' lists every option with
%% its values and default. Every function checks its arguments as the
%% escript checks its flags: a bad file name, option or handle gives
%% `{error, Message}' and starts nothing.
%%
%% ```
%% 1> rigidwarp:run("scenarios/head_on_elastic.json", #{engine => reference}).
%% {ok,#{bodies => 2,engine => reference,frames => 101,realtime_factor => 262.5,
%%       scene => <<"head_on_elastic">>,sim_ms => 1000,wall_ms => 4,...}}
%% 2> {ok, Sim} = rigidwarp:start("scenarios/bouncing_200_250.json", #{until => 500}).
%% 3> rigidwarp:view(Sim).
%% {ok,"http://127.0.0.1:8765/"}
%% 4> rigidwarp:await(Sim, 60000).
%% ok
%% 5> rigidwarp:stats(Sim).
%% #{gvt => 500,efficiency => 0.942,rollbacks => 129,status => done,...}
%% 6> {frame, 500, [{<<"s000">>, P, V, undefined, undefined} | _]} = rigidwarp:frames(Sim).
%% 7> rigidwarp:stop(Sim).
%% ok
%% '''
%%
%% The application's environment holds the defaults a site may change
%% (`config/sys.config', or `application:set_env/3' before the call):
%% `viewer_port', the port of view/1 (8765), and `ring_frames', the most
%% frames a started run keeps readable (1024). The application's other
%% modules are internal.
-module(rigidwarp).
-include("rigidwarp.hrl").
-export([run/2, run_scene/2, load/2, help/0, options/0, start/2, stop/1, frames/1, frames/2, frames_after/3,
         subscribe/1, await/2, gvt/1, stats/1, view/1, view/2, format_error/1]).
-export_type([run_options/0, summary/0, error_reason/0, kind/0]).

-type run_options() :: #{engine => timewarp | reference,
                         buckets => pos_integer(), schedulers => pos_integer(),
                         watchdog_ms => pos_integer(),
                         %% times in ms; whole microseconds (a 0.5 ms substep) are fine
                         until => number(), substep => number(),
                         stride => number(), frame_ms => number(),
                         integrator => rw_integrate:integrator(), ccd => boolean(),
                         %% contact groups (timewarp): off runs one entity per body, as the paper
                         groups => boolean(), group_max => pos_integer(),
                         %% the memory (MiB) the speculative history may take (timewarp):
                         %% the stride is shortened to fit
                         speculation_mb => pos_integer(),
                         %% the C loops (timewarp), where their library loads
                         native => boolean(),
                         %% recovery (timewarp): restarts from the latest checkpoint
                         %% after a fault, at most max_restarts in restart_period_ms
                         max_restarts => non_neg_integer(), restart_period_ms => pos_integer(),
                         checkpoint_ms => non_neg_integer(), ring_size => pos_integer(),
                         frames => file:filename(), resume => boolean(),
                         on_frame => fun((rw_reference:frame()) -> any()),
                         on_progress => fun((map()) -> any())}.
%% The options of run/2 and start/2, times in ms; help/0 lists each with
%% the values it takes and its default. Left out, a time is the scene's.
-type summary() :: #{atom() => term()}.
%% What run/2 returns at the end: the scene, the engine, the body count,
%% sim_ms and wall_ms, realtime_factor, frames, and the engine's counters
%% (events, rollbacks, efficiency... for timewarp).
-type error_reason() :: string() | {crashed, rw_run:who(), term()} | {interrupted, atom(), number() | undefined}.
%% Why run/2 stopped early: a message, a crash past the restart budget, or
%% an interruption ({rw_interrupt, Signal} sent to the process running it)
%% at the last frame's time in ms (undefined before the first frame).
%% format_error/1 makes any of them one line.
-opaque sim() :: rw_timewarp:handle().
%% A running Time Warp simulation (from start/2).
-export_type([sim/0]).

%% The options the Time Warp engine itself takes.
-define(TIMEWARP_KEYS, [buckets, schedulers, nodes, migrate, watchdog_ms, groups, group_max, speculation_mb, max_restarts,
                        restart_period_ms, checkpoint_ms, ring_size, native]).
%% What run/2 takes and start/2 cannot: start/2 hands out frames through
%% the handle (frames/1, subscribe/1), not to a file or a callback.
-define(RUN_ONLY_KEYS, [frames, resume, on_frame, on_progress]).

%% @doc Every option of run/2 and start/2: its name, the values it takes
%% and what it does. help/0 prints this table and load/2 checks options
%% against it, so the two cannot drift apart.
-spec options() -> [{atom(), kind(), string()}].
options() ->
    [{engine, {one_of, [timewarp, reference]}, "timewarp (parallel, default) or reference (sequential; run/2 only)"},
     {until, ms, "simulate up to this time (default: the scene's duration_ms)"},
     {substep, ms, "substep (default: the scene's substep_ms)"},
     {stride, ms, "LVT_ub - GVT, how far bodies may step ahead of GVT (default: the scene's)"},
     {frame_ms, ms, "time between frames (default: the scene's)"},
     {integrator, {one_of, rw_integrate:integrators()}, "the integrator (default: the scene's)"},
     {ccd, boolean, "swept (continuous) collision tests (default: the scene's)"},
     {buckets, count, "TVHT bucket processes (default: the scene's, else 64)"},
     {schedulers, count, "schedulers online while the run lasts (lent by the VM; default: all)"},
     {nodes, nodes, "run over several Erlang nodes: a count (peer nodes started here, each with schedulers "
      "schedulers) or the names of running nodes to use besides this one (default 1)"},
     {migrate, boolean, "over several nodes, place the bodies anew at a checkpoint that finds a tenth of them in "
      "other nodes' space (default true)"},
     {groups, boolean, "step bodies in persistent contact as one entity (default true)"},
     {group_max, {count, rw_regroup:max_allowed()}, "the most bodies in one contact group (default 1024)"},
     {speculation_mb, count, "the memory (MiB) the bodies' history past GVT may take: where the stride would need "
      "more, bodies step ahead of GVT by a shorter one (effective_stride_ms in stats), and while the run holds "
      "more they step less far (memory_holds); either makes throttled true (default "
      ++ integer_to_list(rw_speculation:default_mb()) ++ ")"},
     {native, boolean, "the engine's C loops where their library loads; false runs its Erlang code alone, "
      "with the same frames (default: the application's native, true)"},
     {watchdog_ms, count, "how long GVT may stand still before the run restarts (default 10000)"},
     {max_restarts, non_neg, "restarts after faults allowed within restart_period_ms (default 5)"},
     {restart_period_ms, count, "the period of the restart budget (default 10000)"},
     {checkpoint_ms, non_neg, "wall time between checkpoints (default 500)"},
     {ring_size, count, "latest frames start/2 keeps readable (default 1024; fewer past 32768 body records, but not below 4 for that)"},
     {frames, path, "run/2: write the frames as JSON Lines to this file (\"-\": stdout)"},
     {resume, boolean, "run/2: continue the interrupted run that wrote frames"},
     {on_frame, callback, "run/2: fun(Frame) -> _, for every frame in order"},
     {on_progress, callback, "run/2: fun(Stats) -> _, once per frame"}].

-type kind() :: ms | count | {count, pos_integer()} | non_neg | boolean | path | callback | nodes | {one_of, [atom()]}.
%% The values an option takes: ms is a number above 0, count an integer
%% above 0 ({count, Max}: at most Max), non_neg an integer from 0, path a
%% file name, callback a fun of one argument.

%% @doc Print the API and every option with its values and default.
-spec help() -> ok.
help() ->
    Options = [io_lib:format("    ~-18s ~ts [~ts]~n", [K, Doc, kind_text(Kind)]) || {K, Kind, Doc} <- options()],
    io:put_chars(
      ["rigidwarp shell API\n"
       "  rigidwarp:run(SceneFile, Opts)  run a scene to the end: {ok, Summary} | {error, Reason}\n"
       "  rigidwarp:load(SceneFile, Opts) validate a scene: {ok, Scene} | {error, Message}\n"
       "  rigidwarp:start(SceneFile, Opts) start a Time Warp run in the background: {ok, Sim}\n"
       "  rigidwarp:frames(Sim)           the latest committed frame\n"
       "  rigidwarp:frames(Sim, T)        the committed frame at T ms (while in the ring)\n"
       "  rigidwarp:gvt(Sim)              Global Virtual Time (ms of the latest frame)\n"
       "  rigidwarp:stats(Sim)            GVT, realtime factor, events, rollbacks, status, restarts\n"
       "  rigidwarp:view(Sim)             serve the live 3D viewer: {ok, Url}\n"
       "  rigidwarp:subscribe(Sim)        receive {rw_frame, _, Frame} for every new frame\n"
       "  rigidwarp:await(Sim, TimeoutMs) wait for the run to reach its end time\n"
       "  rigidwarp:stop(Sim)             stop it; no process or table is left behind\n"
       "  Opts (a map; times in ms):\n", Options]),
    ok.

kind_text(ms) -> "ms > 0";
kind_text(count) -> "integer > 0";
kind_text({count, Max}) -> "integer 1.." ++ integer_to_list(Max);
kind_text(non_neg) -> "integer >= 0";
kind_text(boolean) -> "true | false";
kind_text(path) -> "file name";
kind_text(callback) -> "fun/1";
kind_text(nodes) -> "integer 1..64 | [node()]";
kind_text({one_of, Atoms}) -> lists:join(" | ", [atom_to_list(A) || A <- Atoms]).

%% @doc Start a Time Warp run that goes on in the background. The caller
%% is told `{rw_done, _, EndMs}' when it reaches the end, or
%% `{rw_crashed, _, Who, Reason}' when faults have spent its restart
%% budget; frames stay readable until stop/1. It takes the options of
%% run/2 but frames, resume, on_frame and on_progress: a started run gives
%% its frames through frames/1,2 and subscribe/1.
-spec start(file:filename(), run_options()) -> {ok, sim()} | {error, string()}.
start(File, Opts) when is_map(Opts) ->
    case [K || K <- ?RUN_ONLY_KEYS, is_map_key(K, Opts)] of
        [K | _] ->
            {error, lists:flatten(io_lib:format("start/2 does not take ~p: run/2 does; a started simulation gives "
                                                "its frames through frames/1,2 and subscribe/1", [K]))};
        [] ->
            case maps:get(engine, Opts, timewarp) of
                timewarp ->
                    case load(File, Opts) of
                        {ok, Scene} ->
                            case rw_timewarp:start(Scene, (maps:with(?TIMEWARP_KEYS, Opts))#{owner => self()}) of
                                {ok, Sim} -> {ok, Sim};
                                {error, Reason} -> {error, failure(Reason)}
                            end;
                        {error, _} = Error -> Error
                    end;
                Other ->
                    {error, lists:flatten(io_lib:format("start/2 runs the timewarp engine only, not ~p", [Other]))}
            end
    end;
start(_File, Opts) ->
    {error, lists:flatten(io_lib:format("options must be a map, got ~0p", [Opts]))}.

%% @doc Stop a simulation: no process or table of it is left behind.
-spec stop(sim()) -> ok | {error, string()}.
stop(Sim) -> with_sim(Sim, fun rw_timewarp:stop/1).

%% @doc The latest committed frame, or none before the first.
-spec frames(sim()) -> rw_reference:frame() | none | {error, string()}.
frames(Sim) -> frames(Sim, latest).

%% @doc The committed frame at T ms (or the latest), while the frame ring
%% still holds it (the latest ring_size frames: help/0 gives the default);
%% none otherwise.
-spec frames(sim(), latest | number()) -> rw_reference:frame() | none | {error, string()}.
frames(Sim, T) ->
    with_sim(Sim, fun({rw_sim, _, Ring}) ->
                          case T of
                              latest -> rw_ring:latest(Ring);
                              _ when is_number(T), T >= 0 -> rw_ring:frame_at(Ring, T);
                              _ -> {error, lists:flatten(io_lib:format("frame time must be latest or ms >= 0, got ~0p",
                                                                       [T]))}
                          end
                  end).

%% @doc Up to Max committed frames after T ms that are still in the ring,
%% oldest first.
-spec frames_after(sim(), number(), pos_integer()) -> [rw_reference:frame()] | {error, string()}.
frames_after(Sim, T, Max) when is_number(T), is_integer(Max), Max > 0 ->
    with_sim(Sim, fun({rw_sim, _, Ring}) -> rw_ring:frames_after(Ring, T, Max) end);
frames_after(Sim, T, Max) ->
    with_sim(Sim, fun(_) ->
                          {error, lists:flatten(io_lib:format("frames_after needs a time in ms and a positive count, "
                                                              "got ~0p, ~0p", [T, Max]))}
                  end).

%% @doc Counters of a simulation so far: GVT, realtime factor, events,
%% rollbacks, efficiency, restarts. They count committed work only (up to
%% GVT), and stop changing at the end; status is running, done or crashed.
-spec stats(sim()) -> map() | {error, string()}.
stats(Sim) -> with_sim(Sim, fun rw_timewarp:stats/1).

%% @doc Serve the live viewer for Sim on 127.0.0.1, on the port of the
%% application's viewer_port (8765 by default); open the returned URL in a
%% browser.
-spec view(sim()) -> {ok, string()} | {error, string()}.
view(Sim) -> view(Sim, #{}).

%% @doc Serve the live viewer for Sim on the port Opts give (0 picks a free
%% one).
-spec view(sim(), #{port => inet:port_number()}) -> {ok, string()} | {error, string()}.
view(Sim, #{} = Opts) ->
    with_sim(Sim, fun(_) ->
                          ok = rw_viewer:prepare(),
                          case rw_viewer:start({live, Sim}, maps:with([port], Opts)) of
                              {ok, Server} -> {ok, rw_viewer:url(Server)};
                              {error, _} = Error -> Error
                          end
                  end);
view(Sim, Opts) ->
    with_sim(Sim, fun(_) ->
                          {error, lists:flatten(io_lib:format("options must be a map such as #{port => 8765}, got ~0p",
                                                              [Opts]))}
                  end).

%% @doc Global Virtual Time in ms: the time of the latest committed frame
%% (-1 before the first).
-spec gvt(sim()) -> number() | {error, string()}.
gvt(Sim) -> with_sim(Sim, fun({rw_sim, Run, _}) -> rw_run:gvt(Run) end).

%% @doc From now on, receive `{rw_frame, _, Frame}' for every new frame, in
%% order and once, however often the simulation restarts after faults.
%% The simulation waits for its subscribers: it runs at most a few dozen
%% frames (fewer of many bodies) ahead of the messages waiting in a
%% subscriber's mailbox, and goes on as it reads them. A subscriber
%% waiting in await/2 is not waited for.
-spec subscribe(sim()) -> ok | {error, string()}.
subscribe(Sim) -> with_sim(Sim, fun({rw_sim, Run, _}) -> rw_run:subscribe(Run, self(), frames, false) end).

%% @doc Wait until the run reaches its end time (ok), the timeout in ms
%% passes (timeout), or faults spend its restart budget
%% (`{error, {crashed, Who, Reason}}').
-spec await(sim(), timeout()) -> ok | timeout | {error, string() | {crashed, rw_run:who(), term()}}.
await(Sim, Timeout) when Timeout =:= infinity; is_integer(Timeout), Timeout >= 0 ->
    %% a subscriber reads no frame until the end: not waited for meanwhile
    with_sim(Sim, fun({rw_sim, Run, _} = H) ->
                          ok = rw_run:awaiting(Run, self(), true),
                          try await_end(H, Timeout)
                          after rw_run:awaiting(Run, self(), false)
                          end
                  end);
await(Sim, Timeout) ->
    with_sim(Sim, fun(_) ->
                          {error, lists:flatten(io_lib:format("timeout must be infinity or ms >= 0, got ~0p",
                                                              [Timeout]))}
                  end).

await_end({rw_sim, Run, _} = H, Timeout) ->
    case rw_run:status(Run) of
        done -> ok;
        {crashed, Who, Reason} -> {error, {crashed, Who, Reason}};
        running when Timeout =/= infinity, Timeout =< 0 -> timeout;
        running ->
            receive
                {rw_done, Run, _} -> await_end(H, Timeout);
                {rw_crashed, Run, _, _} -> await_end(H, Timeout)
            after 50 -> await_end(H, case Timeout of infinity -> infinity; _ -> Timeout - 50 end)
            end
    end.

%% Every call on a simulation handle checks it first, as the escript
%% checks its flags: a wrong argument or a stopped simulation is an
%% {error, Message}, not a crash.
with_sim({rw_sim, Run, _} = Sim, Fun) ->
    case rw_run:is_run(Run) of
        true ->
            try Fun(Sim)
            catch
                exit:{noproc, _} -> stopped();
                exit:{normal, _} -> stopped();
                exit:{shutdown, _} -> stopped();
                error:badarg -> stopped()
            end;
        false -> stopped()
    end;
with_sim(Other, _Fun) ->
    {error, lists:flatten(io_lib:format("not a simulation (use the Sim that rigidwarp:start/2 returned), got ~0P",
                                        [Other, 8]))}.

stopped() -> {error, "the simulation has been stopped"}.

%% @doc Load and validate a scene with the overrides in Opts (until,
%% substep, stride, frame_ms, integrator, ccd) and check the other options.
%% The error is one line naming the file, the JSON path and the problem.
-spec load(file:filename(), run_options()) -> {ok, #scene{}} | {error, string()}.
load(File, Opts) ->
    case check_file(File) andalso check_options(Opts) of
        false ->
            {error, lists:flatten(io_lib:format("the scene file must be a string (a path), got ~0p", [File]))};
        ok ->
            case rw_scene:load(File, overrides(Opts)) of
                {ok, Scene} ->
                    case check_processes(Scene, Opts) of
                        ok -> {ok, Scene};
                        {error, _} = Error -> Error
                    end;
                {error, E} -> {error, rw_scene:format_error(E)}
            end;
        {error, _} = Error ->
            Error
    end.

%% @doc Run a scene to its end. With `frames => File' the frames go to File
%% as JSON Lines ("-" is stdout; a regular file is written as File.part,
%% with a checkpoint beside it, and renamed at the end; FIFOs and devices
%% are written in place); `resume => true' continues an interrupted run of
%% the same scene and options from its latest checkpoint. Whatever
%% happens, nothing of the run is left behind but the frames so far.
-spec run(file:filename(), run_options()) -> {ok, summary()} | {error, error_reason()}.
run(File, Opts) ->
    case load(File, Opts) of
        {ok, Scene} -> run_scene(Scene, Opts);
        {error, _} = Error -> Error
    end.

%% @doc Run a scene that load/2 returned, as run/2 does.
-spec run_scene(#scene{}, run_options()) -> {ok, summary()} | {error, error_reason()}.
run_scene(Scene, Opts) ->
    Engine = maps:get(engine, Opts, timewarp),
    case open_output(Scene, Opts) of
        {ok, From} ->
            ok = load_engine(),
            T0 = erlang:monotonic_time(microsecond),
            Result = try run_engine(Engine, Scene, From, Opts)
                     catch
                         throw:{rw_interrupt, Signal, Ms} -> {error, {interrupted, Signal, Ms}};
                         error:{rw_output, Message} -> {error, Message};
                         Class:Raised:Stack -> {error, {raised, Class, Raised, Stack}}
                     end,
            case Result of
                {ok, Stats} ->
                    Wall = erlang:monotonic_time(microsecond) - T0,
                    case close_output(finish) of
                        ok -> {ok, summary(Scene, Engine, From, Stats, Wall)};
                        {error, _} = Error -> Error
                    end;
                {error, Why} ->
                    ok = close_output(suspend),
                    {error, failure(Why)}
            end;
        {error, _} = Error ->
            Error
    end.

%% @doc One line for any error of run/2 and run_scene/2.
-spec format_error(error_reason()) -> string().
format_error({crashed, Who, {{too_many_cells, Message}, _Stack}}) ->
    lists:flatten(io_lib:format("the simulation crashed past its restart budget: ~0p died: ~ts", [Who, Message]));
format_error({crashed, Who, Reason}) ->
    lists:flatten(io_lib:format("the simulation crashed past its restart budget: ~0p died: ~0P", [Who, Reason, 12]));
format_error({interrupted, Signal, undefined}) ->
    lists:flatten(io_lib:format("interrupted by ~s before the first frame", [Signal]));
format_error({interrupted, Signal, Ms}) ->
    lists:flatten(io_lib:format("interrupted by ~s at t=~p ms", [Signal, Ms]));
format_error(Message) when is_list(Message) -> Message.

%% The application started and every engine module loaded before the
%% clock starts: wall_ms is the simulation's. The escript loads modules
%% from its archive on first call, 20 ms of a Parallel 500 run that
%% would otherwise count against it (and against the speedups).
load_engine() ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    Mods = lists:append([Ms || App <- [rigidwarp, rw_physics], {ok, Ms} <- [application:get_key(App, modules)]]),
    code:ensure_modules_loaded(Mods).

%% Where the frames and checkpoints of a run go: the output (rw_output),
%% kept in this process's dictionary while the run lasts (the engines call
%% back into this process), and on_frame.
-define(OUTPUT, {?MODULE, output}).

open_output(Scene, #{frames := Path} = Opts) ->
    %% open/3 refuses what check/2 would, before it touches anything
    case rw_output:open(Path, rw_scene:fingerprint(Scene), maps:get(resume, Opts, false)) of
        {ok, Out, From} ->
            put(?OUTPUT, Out),
            {ok, From};
        {error, _} = Error -> Error
    end;
open_output(_Scene, #{resume := true}) ->
    {error, "resume needs frames (the file of the run to continue)"};
open_output(_Scene, _Opts) ->
    {ok, fresh}.

close_output(How) ->
    case erase(?OUTPUT) of
        undefined -> ok;
        Out when How =:= finish -> rw_output:finish(Out);
        Out -> rw_output:suspend(Out)
    end.

write_frame(Frame) -> put(?OUTPUT, rw_output:frame(get(?OUTPUT), Frame)).

write_checkpoint(Checkpoint) -> put(?OUTPUT, rw_output:checkpoint(get(?OUTPUT), Checkpoint)).

%% The frame sink: the output, then on_frame; none when neither wants frames.
sink(Opts) ->
    case {get(?OUTPUT), maps:get(on_frame, Opts, none)} of
        {undefined, none} -> none;
        {undefined, User} -> User;
        {_, none} -> fun write_frame/1;
        {_, User} -> fun(F) -> write_frame(F), User(F) end
    end.

checkpoint_sink() ->
    case get(?OUTPUT) of
        undefined -> #{};
        _ -> #{on_checkpoint => fun write_checkpoint/1}
    end.

run_engine(reference, Scene0, From, Opts) ->
    Scene = case From of fresh -> Scene0; _ -> rw_scene:from_checkpoint(Scene0, From) end,
    End = rw_scene:duration_ms(Scene),
    Sink = case sink(Opts) of none -> fun(_) -> ok end; S -> S end,
    Progress = case maps:find(on_progress, Opts) of
                   {ok, P} ->
                       T0 = erlang:monotonic_time(millisecond),
                       Start = rw_scene:ms(Scene, Scene#scene.start),
                       fun(T) ->
                               Wall = max(1, erlang:monotonic_time(millisecond) - T0),
                               P(#{gvt => T, end_ms => End, wall_ms => Wall, realtime_factor => (T - Start) / Wall})
                       end;
                   error -> fun(_) -> ok end
               end,
    %% the reference runs in this process: a signal's message is seen
    %% between frames
    OnFrame = fun({frame, T, _} = F) ->
                      Sink(F),
                      Progress(T),
                      receive {rw_interrupt, Signal} -> throw({rw_interrupt, Signal, T})
                      after 0 -> ok
                      end
              end,
    rw_reference:run(Scene, maps:merge(#{on_frame => OnFrame},
                                       maps:merge(checkpoint_sink(), maps:with([checkpoint_ms], Opts))));
run_engine(timewarp, Scene, From, Opts) ->
    TwOpts0 = maps:merge(maps:with([on_progress | ?TIMEWARP_KEYS], Opts), checkpoint_sink()),
    TwOpts1 = case From of fresh -> TwOpts0; _ -> TwOpts0#{from => From} end,
    %% no sink, no frames out of the engine (only their times)
    TwOpts = case sink(Opts) of none -> TwOpts1; Sink -> TwOpts1#{on_frame => Sink} end,
    rw_timewarp:run(Scene, TwOpts).

failure({crashed, _, _} = Crash) -> Crash;
failure({interrupted, _, _} = Interrupt) -> Interrupt;
failure({raised, error, {too_many_cells, Message}, _Stack}) -> "the run stopped: " ++ Message;
failure({raised, Class, Reason, Stack}) ->
    lists:flatten(io_lib:format("the run stopped: ~p:~0P in ~0P", [Class, Reason, 12, Stack, 8]));
failure({schedulers, Message}) -> Message;
failure({nodes, Message}) -> Message;
failure(Message) when is_list(Message) -> Message;
failure(Other) -> lists:flatten(io_lib:format("~0P", [Other, 20])).

%% The engine's own counters, plus what every run reports (sim_ms: the
%% simulated time this run computed, from its checkpoint when it resumed).
summary(#scene{name = Name, substep = Dt, stride = Stride, spheres = Spheres} = Scene, Engine, From, Stats, WallUs) ->
    WallMs = WallUs / 1000.0,
    StartMs = case From of fresh -> 0; {checkpoint, _, Ms, _} -> Ms end,
    SimMs = rw_scene:duration_ms(Scene) - StartMs,
    Resumed = case From of fresh -> #{}; _ -> #{resumed_from_ms => StartMs} end,
    %% the run's progress figures (status, GVT, start and end, the lead)
    %% say nothing once it has ended
    %% (the reference engine is Erlang alone)
    maps:merge(maps:without([status, gvt, start_ms, end_ms, max_lvt], maps:merge(#{native => false}, Stats)),
               Resumed#{scene => Name, engine => Engine, bodies => length(Spheres),
                        substep_ms => rw_scene:ms(Scene, Dt), stride_ms => rw_scene:ms(Scene, Stride),
                        sim_ms => SimMs, wall_ms => round(WallMs), realtime_factor => SimMs / max(WallMs, 0.001)}).

check_file(File) when is_list(File); is_binary(File) ->
    try unicode:characters_to_list(File) of
        L when is_list(L), L =/= [] -> true;
        _ -> false
    catch error:_ -> false
    end;
check_file(_) -> false.

check_options(Opts) when is_map(Opts) ->
    Table = options(),
    case [K || K <- maps:keys(Opts), not lists:keymember(K, 1, Table)] of
        [K | _] ->
            {error, lists:flatten(io_lib:format("unknown option ~0p (known: ~s)",
                                                [K, lists:join(", ", [atom_to_list(N) || {N, _, _} <- Table])]))};
        [] ->
            check_values([{K, V, element(2, lists:keyfind(K, 1, Table))} || {K, V} <- lists:sort(maps:to_list(Opts))])
    end;
check_options(Opts) ->
    {error, lists:flatten(io_lib:format("options must be a map, got ~0P", [Opts, 8]))}.

check_values([]) -> ok;
check_values([{K, V, Kind} | Rest]) ->
    case valid(Kind, V) of
        true -> check_values(Rest);
        false -> {error, lists:flatten(io_lib:format("bad value for option ~s: ~0P (~s)", [K, V, 8, kind_text(Kind)]))}
    end.

valid(ms, V) -> is_number(V) andalso V > 0;
valid(count, V) -> is_integer(V) andalso V > 0 andalso V =< 1 bsl 20;
valid({count, Max}, V) -> is_integer(V) andalso V > 0 andalso V =< Max;
valid(non_neg, V) -> is_integer(V) andalso V >= 0 andalso V =< 1 bsl 30;
valid(boolean, V) -> is_boolean(V);
valid(path, V) -> is_list(V) orelse is_binary(V);
valid(callback, V) -> is_function(V, 1);
valid(nodes, V) -> rw_nodes:check(V) =:= ok;
valid({one_of, Atoms}, V) -> lists:member(V, Atoms).

%% A Time Warp run's bucket and body processes within the VM's process
%% limit (beyond it the run would start and then fail with system_limit).
check_processes(#scene{spheres = Spheres, buckets = SceneBuckets, file = File}, Opts) ->
    %% (64: rw_run's default)
    Buckets = maps:get(buckets, Opts, case SceneBuckets of undefined -> 64; _ -> SceneBuckets end),
    Fits = rw_scene_limits:buckets(Buckets, length(Spheres), erlang:system_info(process_limit),
                                   erlang:system_info(process_count)),
    case maps:get(engine, Opts, timewarp) =:= timewarp andalso Fits of
        {error, Msg} when is_map_key(buckets, Opts) -> {error, "bad value for option buckets: " ++ Msg};
        {error, Msg} when File =:= undefined -> {error, "$.buckets: " ++ Msg};
        {error, Msg} -> {error, File ++ ": $.buckets: " ++ Msg};
        _ -> ok
    end.

overrides(Opts) ->
    maps:from_list([{Scene, V} || {Opt, Scene} <- [{until, duration_ms}, {substep, substep_ms},
                                                   {stride, stride_ms}, {frame_ms, frame_ms},
                                                   {integrator, integrator}, {ccd, ccd}],
                                  {ok, V} <- [maps:find(Opt, Opts)]]).
