%% Runs a scene on the Time Warp engine: starts one simulation tree under
%% rw_sims_sup, starts a body per sphere, and collects frames and counters.
-module(rw_timewarp).
-include("rigidwarp.hrl").
-export([start/2, run/2, stop/1, stats/1, progress/2, default_buckets/0, default_group_max/0, end_ms/1, lvt_slot/1]).
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

-define(STAT_NAMES, [events, antievents, primary_rollbacks, secondary_rollbacks,
                     rolled_back_substeps, computed_substeps,
                     tvht_reductions, integrate_reductions, rollback_reductions, gvt_reductions, rollback_calls_reductions,
                     steps, regroups]).
-define(PROFILE_NAMES, [tvht_reductions, integrate_reductions, rollback_reductions, gvt_reductions, rollback_calls_reductions]).

-spec default_buckets() -> pos_integer().
default_buckets() -> 64.

%% The most bodies the engine steps as one contact group, by default: a
%% group is one process, and groups should remain many enough to keep every
%% scheduler busy.
-spec default_group_max() -> pos_integer().
default_group_max() -> 64.

%% Bodies may regroup at frame times at least 8 substeps apart (every
%% frame in the paper's scenes: 10 ms), planned when GVT reaches the
%% regroup point before (rw_gvt): a new persistent contact is stepped as
%% one group one or two periods after its bodies have met often enough to
%% say so. Frame times are sync points anyway; regroup points of their own
%% (every 16 substeps) added a commit per body every 16 ms, 2-5 % of the
%% time of scenes that never regroup.
period(#scene{substep = Dt, frame = F}) -> F * max(1, (8 * Dt + F - 1) div F).

%% Start a simulation; it runs on its own until the scene's end.
-spec start(#scene{}, options()) -> {ok, handle()} | {error, term()}.
start(#scene{spheres = Spheres, initial = Initial, duration = End} = Scene, Opts) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    NBuckets = case Scene#scene.buckets of
                   undefined -> maps:get(buckets, Opts, default_buckets());
                   B -> maps:get(buckets, Opts, B)
               end,
    case supervisor:start_child(rw_sims_sup, [Scene, NBuckets]) of
        {ok, Sup} ->
            #{tables := TablesPid, gvt := Gvt, buckets := Buckets, bodies := BodySup} = rw_sim_sup:children(Sup),
            #{records := Records, counts := Counts, ring := Ring, plans := Plans, owners := Owners, met := Met} =
                rw_sim_tables:tables(TablesPid),
            Period = case {maps:get(groups, Opts, true), maps:find(regroup_every, Opts)} of
                         {false, _} -> 0;
                         {true, {ok, Every}} -> Every * Scene#scene.stride;
                         {true, error} -> period(Scene)
                     end,
            Sim = #sim{scene = Scene, n = length(Spheres), end_t = End, buckets = Buckets, gvt = Gvt,
                       records = Records, counts = Counts, ring = Ring,
                       stats = counters:new(length(?STAT_NAMES), [write_concurrency]),
                       profile = maps:get(profile, Opts, false),
                       lvts = atomics:new(lvt_slot(lists:max([0 | [I || #sphere{idx = I} <- Spheres]])), [{signed, false}]),
                       gvt_now = new_gvt(),
                       period = Period,
                       group_max = maps:get(group_max, Opts, default_group_max()),
                       grouping = maps:get(grouping, Opts, persistent),
                       plans = Plans, owners = Owners, met = Met},
            %% every body holds the simulation record: not the whole scene's
            %% bodies, which it never reads (a copy per body fills the heaps)
            BodySim = Sim#sim{scene = Scene#scene{spheres = [], initial = []}},
            Bodies = [begin
                          {ok, Pid} = supervisor:start_child(BodySup, [BodySim, Sphere, St]),
                          Pid
                      end || {Sphere, St} <- lists:zip(Spheres, Initial)],
            _ = case maps:find(delay, Opts) of
                {ok, {Seed, MaxMs}} -> [P ! {delay, Seed + I, MaxMs} || {I, P} <- lists:zip(lists:seq(1, length(Bodies)), Bodies)];
                error -> ok
            end,
            Sim#sim.profile andalso lists:foreach(fun(B) -> rw_bucket:profile(B, Sim#sim.stats) end,
                                                  tuple_to_list(Buckets)),
            _ = case maps:get(subscribe, Opts, false) of
                    false -> ok;
                    What -> rw_gvt:subscribe(Gvt, maps:get(owner, Opts, self()), What)
                end,
            ok = rw_gvt:go(Gvt, Sim, Bodies, Opts),
            [P ! go || P <- Bodies],
            {ok, #{sup => Sup, gvt => Gvt, ring => Ring, sim => Sim,
                   started => erlang:monotonic_time(millisecond)}};
        {error, _} = Error ->
            Error
    end.

%% Where body Idx publishes its LVT in #sim.lvts: one 64-byte cache line
%% per body, so that bodies on different cores do not share lines.
-spec lvt_slot(non_neg_integer()) -> pos_integer().
lvt_slot(Idx) -> Idx * 8 + 1.

new_gvt() ->
    Ref = atomics:new(1, [{signed, true}]),
    ok = atomics:put(Ref, 1, -1),
    Ref.

%% The end time in ms.
-spec end_ms(#sim{}) -> number().
end_ms(#sim{end_t = End, scene = Scene}) -> rw_scene:ms(Scene, End).

-spec stop(handle()) -> ok.
stop(#{sup := Sup}) ->
    _ = supervisor:terminate_child(rw_sims_sup, Sup),
    ok.

-spec stats(handle()) -> #{atom() => number()}.
stats(#{sim := #sim{stats = Ref, n = N, end_t = End, scene = #scene{substep = Dt}, profile = Profile}}) ->
    All = maps:from_list(lists:zip(?STAT_NAMES, [counters:get(Ref, I) || I <- lists:seq(1, length(?STAT_NAMES))])),
    Raw = case Profile of
              true ->
                  %% a rollback's bucket calls are counted by the buckets
                  #{rollback_reductions := Rb, rollback_calls_reductions := Calls} = All,
                  maps:remove(rollback_calls_reductions, All#{rollback_reductions := max(0, Rb - Calls)});
              false -> maps:without(?PROFILE_NAMES, All)
          end,
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
