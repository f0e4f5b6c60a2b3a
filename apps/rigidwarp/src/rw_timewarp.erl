%% Runs a scene on the Time Warp engine: starts one simulation tree under
%% rw_sims_sup, starts a body per sphere, and collects frames and counters.
-module(rw_timewarp).
-include("rigidwarp.hrl").
-export([start/2, run/2, stop/1, stats/1, progress/2, default_buckets/0, end_ms/1]).
-export_type([handle/0, options/0]).

-type handle() :: #{sup := pid(), gvt := pid(), ring := ets:tid(), sim := #sim{}, started := integer()}.
-type options() :: #{buckets => pos_integer(), owner => pid(),
                     %% the owner hears of every frame, or of its time only
                     subscribe => false | frames | times,
                     groups => boolean(), group_max => pos_integer(),
                     %% (tests) regroup points this many strides apart, groups of
                     %% all bodies near each other however they move
                     regroup_every => pos_integer(), grouping => persistent | eager,
                     watchdog_ms => pos_integer(), ring_size => pos_integer(), profile => boolean(),
                     delay => {Seed :: integer(), MaxMs :: non_neg_integer()},
                     on_frame => fun((rw_reference:frame()) -> any()),
                     on_progress => fun((map()) -> any())}.

-spec default_buckets() -> pos_integer().
default_buckets() -> 64.

%% Start a simulation; it runs on its own until the scene's end.
-spec start(#scene{}, options()) -> {ok, handle()} | {error, term()}.
start(Scene, Opts) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    NBuckets = case Scene#scene.buckets of
                   undefined -> maps:get(buckets, Opts, default_buckets());
                   B -> maps:get(buckets, Opts, B)
               end,
    Subscribers = case maps:get(subscribe, Opts, false) of
                      false -> [];
                      What -> [{maps:get(owner, Opts, self()), What}]
                  end,
    case rw_sim_sup:start(Scene, NBuckets, Opts#{subscribers => Subscribers}) of
        {ok, Sup, #sim{gvt = Gvt, ring = Ring} = Sim} ->
            {ok, #{sup => Sup, gvt => Gvt, ring => Ring, sim => Sim, started => erlang:monotonic_time(millisecond)}};
        {error, _} = Error ->
            Error
    end.

%% The end time in ms.
-spec end_ms(#sim{}) -> number().
end_ms(#sim{end_t = End, scene = Scene}) -> rw_scene:ms(Scene, End).

-spec stop(handle()) -> ok.
stop(#{sup := Sup}) ->
    _ = supervisor:terminate_child(rw_sims_sup, Sup),
    ok.

-spec stats(handle()) -> #{atom() => number()}.
stats(#{sim := #sim{stats = Ref, n = N, end_t = End, scene = #scene{substep = Dt}, profile = Profile}}) ->
    Raw = rw_stats:read(Ref, Profile),
    Committed = N * (End div Dt),
    Computed = maps:get(computed_substeps, Raw),
    Raw#{rollbacks => maps:get(primary_rollbacks, Raw) + maps:get(secondary_rollbacks, Raw),
         committed_substeps => Committed,
         efficiency => case Computed of 0 -> 1.0; _ -> Committed / Computed end}.

%% How far a running simulation is: GVT, how far the fastest body is ahead
%% of it, realtime factor so far and the counters (times in ms, as rw_gvt:gvt/1
%% gives GVT).
-spec progress(handle(), number()) -> map().
progress(#{sim := #sim{lvts = Lvts, end_t = End, scene = Scene}, started := T0} = H, Gvt) ->
    #{size := Size} = atomics:info(Lvts),
    Lead = lists:max([atomics:get(Lvts, I) || I <- lists:seq(1, Size, 8)]),
    Wall = max(1, erlang:monotonic_time(millisecond) - T0),
    (stats(H))#{gvt => Gvt, end_ms => rw_scene:ms(Scene, End),
                max_lvt => rw_scene:ms(Scene, Lead), wall_ms => Wall, realtime_factor => max(Gvt, 0) / Wall}.

%% Run to the end, calling on_frame for every committed frame in order
%% (without on_frame, the frames stay in the engine: only their times come
%% here, for on_progress and the count).
-spec run(#scene{}, options()) -> {ok, map()} | {error, term()}.
run(Scene, Opts) ->
    What = case maps:is_key(on_frame, Opts) of true -> frames; false -> times end,
    %% nobody reads the ring of a run (it has no handle to read it with):
    %% only the latest frame's records are kept, not the last 1024 frames'
    %% (deleting those at the end cost Parallel 500 40 ms)
    case start(Scene, maps:merge(#{ring_size => 1}, Opts#{owner => self(), subscribe => What})) of
        {ok, #{sup := Sup, gvt := Gvt} = H} ->
            OnFrame = maps:get(on_frame, Opts, fun(_) -> ok end),
            OnTime = case maps:find(on_progress, Opts) of
                         {ok, P} -> fun(T) -> P(progress(H, T)) end;
                         error -> fun(_) -> ok end
                     end,
            MRef = erlang:monitor(process, Sup),
            Result = try collect(Gvt, MRef, OnFrame, OnTime, 0)
                     after
                         erlang:demonitor(MRef, [flush])
                     end,
            Stats = stats(H),
            stop(H),
            flush(Gvt),
            case Result of
                {ok, Frames} -> {ok, Stats#{frames => Frames}};
                Error -> Error
            end;
        Error ->
            Error
    end.

collect(Gvt, MRef, OnFrame, OnTime, N) ->
    receive
        {rw_frame, Gvt, {frame, T, _} = Frame} ->
            OnFrame(Frame),
            OnTime(T),
            collect(Gvt, MRef, OnFrame, OnTime, N + 1);
        {rw_frame_time, Gvt, T} ->
            OnTime(T),
            collect(Gvt, MRef, OnFrame, OnTime, N + 1);
        {rw_done, Gvt, _End} -> {ok, N};
        {rw_stalled, Gvt, G, Report} -> {error, {stalled, G, Report}};
        {'DOWN', MRef, process, _, Reason} -> {error, {crashed, Reason}}
    end.

flush(Gvt) ->
    receive
        {rw_frame, Gvt, _} -> flush(Gvt);
        {rw_frame_time, Gvt, _} -> flush(Gvt);
        {rw_stalled, Gvt, _, _} -> flush(Gvt)
    after 0 -> ok
    end.
