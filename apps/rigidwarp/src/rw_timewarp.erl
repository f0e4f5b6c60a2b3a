%% Runs a scene on the Time Warp engine: a run (rw_run) under rw_sims_sup,
%% which starts the simulation's tree and restarts it after a fault, and
%% the caller's side of it: the frames, checkpoints and counters.
-module(rw_timewarp).
-include("rigidwarp.hrl").
-export([start/2, run/2, stop/1, stats/1, scene/1]).
-export_type([handle/0, options/0]).

%% The run's process and its frame ring (rw_ring), read without asking it:
%% a short term, which the shell prints on one line.
-type handle() :: {rw_sim, pid(), ets:tid()}.
-type options() :: #{buckets => pos_integer(), schedulers => pos_integer(),
                     %% the owner hears {rw_done, Run, EndMs} and {rw_crashed, Run, Who,
                     %% Reason}, and of every frame or its time if it subscribes;
                     %% with ack, it acknowledges each of those it has handled
                     %% (rw_run:ack/1), else the run reads how many wait in its mailbox
                     owner => pid(), subscribe => none | frames | times, ack => boolean(),
                     groups => boolean(), group_max => pos_integer(), speculation_mb => pos_integer(),
                     %% the engine's C loops where their library is loaded (default: rw_native:default/0)
                     native => boolean(),
                     %% (tests) regroup points this many strides apart, groups of
                     %% all bodies near each other however they move
                     regroup_every => pos_integer(), grouping => persistent | eager,
                     watchdog_ms => pos_integer(), ring_size => pos_integer(), profile => boolean(),
                     %% false: nobody reads this run's frames (nor subscribes to them),
                     %% so that bodies keep their records only where the engine reads
                     %% them (run/2 without on_frame: false)
                     read_frames => boolean(),
                     %% record the run's tasks into this table (rw_trace), on one node
                     trace => ets:tid(),
                     delay => {Seed :: integer(), MaxMs :: non_neg_integer()},
                     max_restarts => non_neg_integer(), restart_period_ms => pos_integer(),
                     checkpoint_ms => non_neg_integer(), from => rw_reference:checkpoint(),
                     on_frame => fun((rw_reference:frame()) -> any()),
                     on_checkpoint => fun((rw_reference:checkpoint()) -> any()),
                     on_progress => fun((map()) -> any())}.

-define(RUN_KEYS, [buckets, schedulers, nodes, migrate, groups, group_max, speculation_mb, regroup_every, grouping, watchdog_ms, ring_size, profile, read_frames,
                   trace, delay, max_restarts, restart_period_ms, checkpoint_ms, from, native]).

%% Start a simulation; it runs on its own until the scene's end.
-spec start(#scene{}, options()) -> {ok, handle()} | {error, term()}.
start(Scene, Opts) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    Owner = maps:get(owner, Opts, self()),
    Sub = {Owner, maps:get(subscribe, Opts, none), maps:is_key(on_checkpoint, Opts)},
    Acks = [Owner || maps:get(ack, Opts, false)],
    case rw_run:start(Scene, (maps:with(?RUN_KEYS, Opts))#{subscribers => [Sub], acks => Acks}) of
        {ok, Run} -> {ok, {rw_sim, Run, rw_run:ring(Run)}};
        {error, _} = Error -> Error
    end.

-spec scene(handle()) -> #scene{}.
scene({rw_sim, Run, _}) -> rw_run:scene(Run).

-spec stop(handle()) -> ok.
stop({rw_sim, Run, _}) -> rw_run:stop(Run).

%% The counters, GVT and status of a run (rw_run:stats/1).
-spec stats(handle()) -> map().
stats({rw_sim, Run, _}) -> rw_run:stats(Run).

%% Run to the end, calling on_frame for every committed frame in order
%% (without on_frame, the frames stay in the engine: only their times come
%% here, for on_progress and the count) and on_checkpoint for checkpoints.
%% The run goes no further ahead of on_frame than a window of frames
%% (rw_flow): this process acknowledges each frame once on_frame and
%% on_progress have returned, so a slow on_frame holds GVT and frames do
%% not pile up in its mailbox, nor do messages it sends itself count.
%% {rw_interrupt, Signal} sent to the caller stops the run:
%% {error, {interrupted, Signal, LastFrameMs}} (undefined before the first frame). The run is stopped however
%% this returns, a callback's exception included.
-spec run(#scene{}, options()) -> {ok, map()} | {error, term()}.
run(Scene, Opts) ->
    What = case maps:is_key(on_frame, Opts) of true -> frames; false -> times end,
    %% nobody reads the ring of a run (it has no handle to read it with):
    %% only the latest frame's records are kept, not the last 1024 frames'
    %% (deleting those at the end would count in the run's wall time), and
    %% without on_frame only those the engine reads itself
    case start(Scene, maps:merge(#{ring_size => 1, read_frames => What =:= frames},
                                 Opts#{owner => self(), subscribe => What, ack => true})) of
        {ok, {rw_sim, Run, _} = H} ->
            Calls = #{frame => maps:get(on_frame, Opts, fun(_) -> ok end),
                      checkpoint => maps:get(on_checkpoint, Opts, fun(_) -> ok end),
                      time => case maps:find(on_progress, Opts) of
                                  {ok, P} -> fun(T) -> P(progress(T, stats(H))) end;
                                  error -> fun(_) -> ok end
                              end},
            MRef = erlang:monitor(process, Run),
            try collect(Run, MRef, Calls, 0, undefined) of
                {ok, Frames} -> {ok, (stats(H))#{frames => Frames}};
                Error -> Error
            after
                erlang:demonitor(MRef, [flush]),
                stop(H),
                flush(Run)
            end;
        Error ->
            Error
    end.

%% Progress as of the frame at T ms just delivered (the simulation may be
%% further on already).
progress(T, #{start_ms := Start, wall_ms := Wall} = Stats) ->
    Stats#{gvt => T, realtime_factor => max(0, T - Start) / Wall}.

collect(Run, MRef, #{frame := OnFrame, time := OnTime, checkpoint := OnCheckpoint} = Calls, N, Last) ->
    receive
        {rw_frame, Run, {frame, T, _} = Frame} ->
            OnFrame(Frame),
            OnTime(T),
            ok = rw_run:ack(Run),
            collect(Run, MRef, Calls, N + 1, T);
        {rw_frame_time, Run, T} ->
            OnTime(T),
            ok = rw_run:ack(Run),
            collect(Run, MRef, Calls, N + 1, T);
        {rw_checkpoint, Run, Checkpoint} ->
            OnCheckpoint(Checkpoint),
            collect(Run, MRef, Calls, N, Last);
        {rw_done, Run, _End} -> {ok, N};
        {rw_crashed, Run, Who, Reason} -> {error, {crashed, Who, Reason}};
        {rw_interrupt, Signal} -> {error, {interrupted, Signal, Last}};
        {'DOWN', MRef, process, _, Reason} -> {error, {crashed, run, Reason}}
    end.

flush(Run) ->
    receive
        {rw_frame, Run, _} -> flush(Run);
        {rw_frame_time, Run, _} -> flush(Run);
        {rw_checkpoint, Run, _} -> flush(Run);
        {rw_done, Run, _} -> flush(Run);
        {rw_crashed, Run, _, _} -> flush(Run)
    after 0 -> ok
    end.
