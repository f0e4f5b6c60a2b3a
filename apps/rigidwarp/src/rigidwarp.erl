%% The shell API of rigidwarp.
%%
%%   1> rigidwarp:run("scenarios/head_on_elastic.json", #{engine => reference}).
%%   {ok, #{scene => <<"head_on_elastic">>, realtime_factor => ..., ...}}
-module(rigidwarp).
-include("rigidwarp.hrl").
-export([run/2, run_scene/2, load/2, help/0, start/2, stop/1, frames/1, frames/2, frames_after/3,
         subscribe/1, await/2, gvt/1, stats/1, view/1, view/2]).
-export_type([run_options/0, summary/0]).

-type run_options() :: #{engine => timewarp | reference,
                         buckets => pos_integer(), schedulers => pos_integer(),
                         watchdog_ms => pos_integer(),
                         %% times in ms; whole microseconds (a 0.5 ms substep) are fine
                         until => number(), substep => number(),
                         stride => number(), frame_ms => number(),
                         integrator => rw_integrate:integrator(), ccd => boolean(),
                         %% contact groups (timewarp): off runs one entity per body, as the paper
                         groups => boolean(), group_max => pos_integer(),
                         frames => file:filename(),
                         on_frame => fun((rw_reference:frame()) -> any()),
                         on_progress => fun((map()) -> any())}.
-type summary() :: #{atom() => term()}.
%% A running Time Warp simulation (from start/2).
-opaque sim() :: rw_timewarp:handle().
-export_type([sim/0]).

-define(OPTION_KEYS, [engine, until, substep, stride, frame_ms, integrator, ccd, frames, on_frame, on_progress,
                      buckets, schedulers, watchdog_ms, groups, group_max]).
%% The options the Time Warp engine itself takes.
-define(TIMEWARP_KEYS, [buckets, watchdog_ms, groups, group_max]).

-spec help() -> ok.
help() ->
    io:put_chars(
      "rigidwarp shell API\n"
      "  rigidwarp:run(SceneFile, Opts)  run a scene to the end, return a summary map\n"
      "      Opts: engine => reference, until => Ms, substep => Ms, stride => Ms,\n"
      "            frame_ms => Ms, integrator => verlet, ccd => true,\n"
      "            frames => \"out.jsonl\", on_frame => fun(Frame) -> _ end\n"
      "  rigidwarp:load(SceneFile, Opts) validate a scene, return {ok, Scene} | {error, Message}\n"
      "  rigidwarp:start(SceneFile, Opts) start a Time Warp run in the background: {ok, Sim}\n"
      "  rigidwarp:frames(Sim)           the latest committed frame\n"
      "  rigidwarp:frames(Sim, T)        the committed frame at T ms (while in the ring)\n"
      "  rigidwarp:gvt(Sim)              Global Virtual Time (ms of the latest frame)\n"
      "  rigidwarp:stats(Sim)            GVT, realtime factor, events, rollbacks... while it runs\n"
      "  rigidwarp:view(Sim)             serve the live 3D viewer: {ok, Url}\n"
      "  rigidwarp:subscribe(Sim)        receive {rw_frame, _, Frame} for every new frame\n"
      "  rigidwarp:await(Sim, TimeoutMs) wait for the run to reach its end time\n"
      "  rigidwarp:stop(Sim)             stop it; no process or table is left behind\n"),
    ok.

%% Start a Time Warp run that goes on in the background. The caller is told
%% {rw_done, _, EndMs} when it reaches the end; frames stay readable until
%% stop/1.
-spec start(file:filename(), run_options()) -> {ok, sim()} | {error, string()}.
start(File, Opts) ->
    case maps:get(engine, Opts, timewarp) of
        timewarp ->
            case load(File, Opts) of
                {ok, Scene} ->
                    case rw_timewarp:start(Scene, (maps:with(?TIMEWARP_KEYS, Opts))#{owner => self()}) of
                        {ok, Sim} -> {ok, Sim};
                        {error, Reason} -> {error, describe_failure(Reason)}
                    end;
                {error, _} = Error -> Error
            end;
        Other ->
            {error, lists:flatten(io_lib:format("start/2 runs the timewarp engine only, not ~p", [Other]))}
    end.

%% Every call on a simulation handle checks it first, as the escript
%% checks its flags: a wrong argument is an {error, Message}, not a crash.
-define(IS_SIM(S), (is_map(S) andalso is_map_key(ring, S) andalso is_map_key(gvt, S)
                    andalso is_map_key(sup, S))).

-spec stop(sim()) -> ok | {error, string()}.
stop(Sim) when ?IS_SIM(Sim) -> rw_timewarp:stop(Sim);
stop(Other) -> not_a_sim(Other).

-spec frames(sim()) -> rw_reference:frame() | none | {error, string()}.
frames(Sim) -> frames(Sim, latest).

-spec frames(sim(), latest | number()) -> rw_reference:frame() | none | {error, string()}.
frames(Sim, T) when ?IS_SIM(Sim) ->
    Ring = maps:get(ring, Sim),
    alive(fun() ->
                  case T of
                      latest -> rw_ring:latest(Ring);
                      _ when is_number(T), T >= 0 -> rw_ring:frame_at(Ring, T);
                      _ -> {error, lists:flatten(io_lib:format("frame time must be latest or ms >= 0, got ~0p", [T]))}
                  end
          end);
frames(Other, _) -> not_a_sim(Other).

%% Up to Max committed frames after T ms that are still in the ring.
-spec frames_after(sim(), number(), pos_integer()) -> [rw_reference:frame()] | {error, string()}.
frames_after(Sim, T, Max) when ?IS_SIM(Sim), is_number(T), is_integer(Max), Max > 0 ->
    alive(fun() -> rw_ring:frames_after(maps:get(ring, Sim), T, Max) end);
frames_after(Sim, T, Max) when ?IS_SIM(Sim) ->
    {error, lists:flatten(io_lib:format("frames_after needs a time in ms and a positive count, got ~0p, ~0p",
                                        [T, Max]))};
frames_after(Other, _, _) -> not_a_sim(Other).

%% Counters of a running (or finished, not yet stopped) simulation.
-spec stats(sim()) -> map() | {error, string()}.
stats(Sim) when ?IS_SIM(Sim) -> alive(fun() -> rw_timewarp:progress(Sim, rw_gvt:gvt(maps:get(gvt, Sim))) end);
stats(Other) -> not_a_sim(Other).

%% Serve the live viewer for Sim on 127.0.0.1 (port 8765 unless Opts say
%% otherwise); open the returned URL in a browser.
-spec view(sim()) -> {ok, string()} | {error, string()}.
view(Sim) -> view(Sim, #{}).

-spec view(sim(), #{port => inet:port_number()}) -> {ok, string()} | {error, string()}.
view(Sim, #{} = Opts) when ?IS_SIM(Sim) ->
    ok = rw_viewer:prepare(),
    case rw_viewer:start({live, Sim}, maps:with([port], Opts)) of
        {ok, Server} -> {ok, rw_viewer:url(Server)};
        {error, _} = Error -> Error
    end;
view(Sim, Opts) when ?IS_SIM(Sim) ->
    {error, lists:flatten(io_lib:format("options must be a map such as #{port => 8765}, got ~0p", [Opts]))};
view(Other, _) -> not_a_sim(Other).

-spec gvt(sim()) -> number() | {error, string()}.
gvt(Sim) when ?IS_SIM(Sim) -> alive(fun() -> rw_gvt:gvt(maps:get(gvt, Sim)) end);
gvt(Other) -> not_a_sim(Other).

-spec subscribe(sim()) -> ok | {error, string()}.
subscribe(Sim) when ?IS_SIM(Sim) -> alive(fun() -> rw_gvt:subscribe(maps:get(gvt, Sim), self(), frames) end);
subscribe(Other) -> not_a_sim(Other).

-spec await(sim(), timeout()) -> ok | timeout | {error, string()}.
await(Sim, Timeout) when ?IS_SIM(Sim), (Timeout =:= infinity orelse (is_integer(Timeout) andalso Timeout >= 0)) ->
    alive(fun() -> await_end(Sim, Timeout) end);
await(Sim, Timeout) when ?IS_SIM(Sim) ->
    {error, lists:flatten(io_lib:format("timeout must be infinity or ms >= 0, got ~0p", [Timeout]))};
await(Other, _) -> not_a_sim(Other).

await_end(#{gvt := Gvt, sim := Sim} = H, Timeout) ->
    End = rw_timewarp:end_ms(Sim),
    case rw_gvt:gvt(Gvt) >= End of
        true -> ok;
        false when Timeout =/= infinity, Timeout =< 0 -> timeout;
        false ->
            receive {rw_done, Gvt, _} -> ok
            after 50 -> await_end(H, case Timeout of infinity -> infinity; _ -> Timeout - 50 end)
            end
    end.

not_a_sim(Other) ->
    {error, lists:flatten(io_lib:format("not a simulation (use the Sim that rigidwarp:start/2 returned), got ~0P",
                                        [Other, 8]))}.

%% A stopped simulation's processes and tables are gone.
alive(Fun) ->
    try Fun()
    catch
        exit:{noproc, _} -> {error, "the simulation has been stopped"};
        error:badarg -> {error, "the simulation has been stopped"}
    end.

%% Load and validate a scene with the overrides in Opts.
-spec load(file:filename(), run_options()) -> {ok, #scene{}} | {error, string()}.
load(File, Opts) ->
    case check_file(File) andalso check_options(Opts) of
        false ->
            {error, lists:flatten(io_lib:format("the scene file must be a string (a path), got ~0p", [File]))};
        ok ->
            case rw_scene:load(File, overrides(Opts)) of
                {ok, Scene} -> {ok, Scene};
                {error, E} -> {error, rw_scene:format_error(E)}
            end;
        {error, _} = Error ->
            Error
    end.

-spec run(file:filename(), run_options()) -> {ok, summary()} | {error, string()}.
run(File, Opts) ->
    case load(File, Opts) of
        {ok, Scene} -> run_scene(Scene, Opts);
        {error, _} = Error -> Error
    end.

%% Run a scene that load/2 returned.
-spec run_scene(#scene{}, run_options()) -> {ok, summary()} | {error, string()}.
run_scene(Scene, Opts) ->
    Engine = maps:get(engine, Opts, timewarp),
    case open_sink(Opts) of
        {ok, Sink, Close} ->
            ok = load_engine(),
            T0 = erlang:monotonic_time(microsecond),
            try run_engine(Engine, Scene, Sink, Opts) of
                {error, Reason} ->
                    ok = Close(abort),
                    {error, describe_failure(Reason)};
                {ok, Stats} ->
                    Wall = erlang:monotonic_time(microsecond) - T0,
                    ok = Close(ok),
                    {ok, summary(Scene, Engine, Stats, Wall)}
            catch
                Class:Reason:Stack ->
                    ok = Close(abort),
                    erlang:raise(Class, Reason, Stack)
            end;
        {error, _} = Error ->
            Error
    end.

%% The application started and every engine module loaded before the
%% clock starts: wall_ms is the simulation's. The escript loads modules
%% from its archive on first call, 20 ms of a Parallel 500 run that
%% would otherwise count against it (and against the speedups).
load_engine() ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    Mods = lists:append([Ms || App <- [rigidwarp, rw_physics], {ok, Ms} <- [application:get_key(App, modules)]]),
    code:ensure_modules_loaded(Mods).

run_engine(reference, Scene, none, Opts) ->
    run_engine(reference, Scene, fun(_) -> ok end, Opts);
run_engine(reference, Scene, Sink, Opts) ->
    End = rw_scene:duration_ms(Scene),
    OnFrame = case maps:find(on_progress, Opts) of
                  {ok, P} ->
                      T0 = erlang:monotonic_time(millisecond),
                      fun({frame, T, _} = F) ->
                              Sink(F),
                              Wall = max(1, erlang:monotonic_time(millisecond) - T0),
                              P(#{gvt => T, end_ms => End, wall_ms => Wall, realtime_factor => T / Wall})
                      end;
                  error -> Sink
              end,
    rw_reference:run(Scene, #{on_frame => OnFrame});
run_engine(timewarp, Scene, Sink, Opts) ->
    TwOpts0 = maps:with([on_progress | ?TIMEWARP_KEYS], Opts),
    %% no sink, no frames out of the engine (only their times)
    TwOpts = case Sink of none -> TwOpts0; _ -> TwOpts0#{on_frame => Sink} end,
    with_schedulers(maps:get(schedulers, Opts, undefined), fun() -> rw_timewarp:run(Scene, TwOpts) end).

with_schedulers(undefined, Fun) -> Fun();
with_schedulers(N, Fun) ->
    Old = erlang:system_flag(schedulers_online, min(N, erlang:system_info(schedulers))),
    try Fun() after erlang:system_flag(schedulers_online, Old) end.

describe_failure({stalled, Gvt, Report}) ->
    lists:flatten(io_lib:format("GVT did not advance past ~p ms:~n~ts", [Gvt, Report]));
describe_failure({crashed, Reason}) ->
    lists:flatten(io_lib:format("the simulation crashed: ~p", [Reason]));
describe_failure(Other) ->
    lists:flatten(io_lib:format("~p", [Other])).

%% Where frames go: a file, on_frame, both, or nowhere (none).
open_sink(Opts) ->
    User = maps:get(on_frame, Opts, none),
    case maps:find(frames, Opts) of
        error ->
            {ok, User, fun(_) -> ok end};
        {ok, File} ->
            case rw_frames:writer(File) of
                {ok, Write, Close} when User =:= none ->
                    {ok, Write, Close};
                {ok, Write, Close} ->
                    {ok, fun(F) -> Write(F), User(F) end, Close};
                {error, Reason} ->
                    {error, lists:flatten(io_lib:format("cannot write frames to ~ts: ~ts",
                                                        [File, file:format_error(Reason)]))}
            end
    end.

%% The engine's own counters, plus what every run reports.
summary(#scene{name = Name, substep = Dt, stride = Stride, spheres = Spheres} = Scene, Engine, Stats, WallUs) ->
    WallMs = WallUs / 1000.0,
    SimMs = rw_scene:duration_ms(Scene),
    Stats#{scene => Name, engine => Engine, bodies => length(Spheres), substep_ms => rw_scene:ms(Scene, Dt),
           stride_ms => rw_scene:ms(Scene, Stride), sim_ms => SimMs, wall_ms => round(WallMs),
           realtime_factor => SimMs / max(WallMs, 0.001)}.

check_file(File) when is_list(File); is_binary(File) ->
    try unicode:characters_to_list(File) of
        L when is_list(L), L =/= [] -> true;
        _ -> false
    catch error:_ -> false
    end;
check_file(_) -> false.

check_options(Opts) when is_map(Opts) ->
    Bad = [K || K <- maps:keys(Opts), not lists:member(K, ?OPTION_KEYS)],
    case Bad of
        [K | _] -> {error, lists:flatten(io_lib:format("unknown option ~p (known: ~p)", [K, ?OPTION_KEYS]))};
        [] -> check_values(maps:to_list(Opts))
    end;
check_options(Opts) ->
    {error, lists:flatten(io_lib:format("options must be a map, got ~p", [Opts]))}.

check_values([]) -> ok;
check_values([{engine, E} | Rest]) when E =:= reference; E =:= timewarp -> check_values(Rest);
check_values([{K, V} | Rest]) when (K =:= buckets orelse K =:= schedulers orelse K =:= watchdog_ms
                                    orelse K =:= group_max),
                                   is_integer(V), V > 0, V =< 1 bsl 20 -> check_values(Rest);
check_values([{K, V} | Rest]) when (K =:= until orelse K =:= substep orelse K =:= stride orelse
                                    K =:= frame_ms), is_number(V), V > 0 -> check_values(Rest);
check_values([{integrator, I} | Rest]) ->
    case lists:member(I, rw_integrate:integrators()) of
        true -> check_values(Rest);
        false -> {error, lists:flatten(io_lib:format("bad value for option integrator: ~p (known: ~p)",
                                                     [I, rw_integrate:integrators()]))}
    end;
check_values([{K, C} | Rest]) when (K =:= ccd orelse K =:= groups), is_boolean(C) -> check_values(Rest);
check_values([{frames, F} | Rest]) when is_list(F); is_binary(F) -> check_values(Rest);
check_values([{K, F} | Rest]) when (K =:= on_frame orelse K =:= on_progress), is_function(F, 1) ->
    check_values(Rest);
check_values([{K, V} | _]) ->
    {error, lists:flatten(io_lib:format("bad value for option ~p: ~p", [K, V]))}.

overrides(Opts) ->
    maps:from_list([{Scene, V} || {Opt, Scene} <- [{until, duration_ms}, {substep, substep_ms},
                                                   {stride, stride_ms}, {frame_ms, frame_ms},
                                                   {integrator, integrator}, {ccd, ccd}],
                                  {ok, V} <- [maps:find(Opt, Opts)]]).
