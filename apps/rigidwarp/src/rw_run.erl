%% One Time Warp simulation from its start to its end, through faults.
%%
%% It owns what must outlive the simulation's processes: the committed
%% records and the frame ring (frames stay readable whatever dies), the
%% latest checkpoint (a committed frame with every body's whole state,
%% rw_reference:checkpoint()), the counters and the subscribers. It starts
%% the simulation's tree (rw_sim_sup) and watches every process in it. When
%% one dies, or GVT stalls, it stops the tree and starts another from the
%% latest checkpoint: a committed frame is a consistent cut that no
%% rollback can reach, so the frames from there on are those of the run
%% that never stopped; the frames delivered already are not delivered
%% again. Past the restart budget (max_restarts within restart_period_ms)
%% the run has crashed: it says so at once, and its frames stay readable
%% until it is stopped.
%%
%% Subscribers hear, with Run = this process: {rw_frame, Run, Frame} or
%% {rw_frame_time, Run, Ms} for every frame, in order and once (frames or
%% times); {rw_checkpoint, Run, Checkpoint} if they asked; {rw_done, Run,
%% EndMs}; {rw_crashed, Run, Who, Reason}. A subscriber of none hears only
%% of the end and of a crash.
%%
%% Backpressure (rw_flow): GVT stops at an allowance instead of running
%% ahead of the subscribers of frames or times. What a subscriber has not
%% handled yet is what it has not acknowledged (ack/1: the subscribers
%% named in the acks option, rw_timewarp:run/2's), else what waits in its
%% mailbox (a process on this node; one on another node, or one waiting
%% in rigidwarp:await/2 for the end, holds nothing). The allowance lives in
%% an atomic that every tree of the run reads, so it survives restarts;
%% while GVT is held there, the subscribers are looked at again every
%% few ms.
-module(rw_run).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start/2, stop/1, is_run/1, subscribe/4, ack/1, awaiting/3, status/1, stats/1, gvt/1, ring/1, scene/1, processes/1,
         nodes/1]).
-export([start_link/2, init/1, handle_call/3, handle_cast/2, handle_info/2, terminate/2]).
-export_type([options/0, status/0, who/0, subscription/0]).

%% The simulation's options (rw_sim, rw_sim_sup), and: buckets; schedulers
%% (rw_schedulers); the restart budget; checkpoint_ms, wall time between
%% checkpoints; from, the checkpoint to start from; subscribers from the
%% start; acks, those of them that acknowledge every frame or time they
%% have handled (ack/1).
-type options() :: #{buckets => pos_integer(), schedulers => pos_integer(), nodes => rw_nodes:spec() | rw_nodes:nodes(),
                     migrate => boolean(),
                     max_restarts => non_neg_integer(), restart_period_ms => pos_integer(),
                     checkpoint_ms => non_neg_integer(), from => rw_reference:checkpoint(),
                     subscribers => [subscription()], acks => [pid()], atom() => term()}.
-type subscription() :: {pid(), none | times | frames, Checkpoints :: boolean()}.
-type who() :: rw_sim_sup:who() | supervisor | stalled.
-type status() :: running | done | {crashed, who(), term()}.

-define(DEFAULT_BUCKETS, 64).
-define(DEFAULT_MAX_RESTARTS, 5).
-define(DEFAULT_RESTART_PERIOD_MS, 10000).
%% How often the subscribers are looked at while GVT is held for them.
-define(FLOW_RECHECK_MS, 10).
%% The options the simulation's tree takes.
-define(SIM_KEYS, [groups, group_max, regroup_every, grouping, profile, delay, watchdog_ms, ring_size,
                   checkpoint_ms, trace, read_frames, speculation_mb, native]).

-record(r, {
    scene :: #scene{},                        % from the run's first start time
    opts :: options(),
    buckets :: pos_integer(),
    records :: ets:tid(),
    ring :: ets:tid(),
    stats :: rw_stats:counters(),
    subs = [] :: [subscription()],
    checkpoint :: rw_reference:checkpoint() | none,
    delivered = -1 :: integer(),              % the last frame delivered, in ticks
    %% backpressure (rw_flow): the allowance, as written in the atomic the
    %% trees read; the messages each acknowledging subscriber has not
    %% acknowledged yet; the subscribers waiting for the end; the timer
    %% that looks at the subscribers again while GVT is held
    flow :: atomics:atomics_ref(),
    allowance :: rw_flow:allowance(),
    unacked = #{} :: #{pid() => non_neg_integer()},
    awaiting = #{} :: #{pid() => true},
    recheck = none :: none | reference(),
    status = running :: status(),
    sup = none :: pid() | none,
    sim :: #sim{} | undefined,
    watched = #{} :: #{reference() => {pid(), rw_sim_sup:who()}},
    restarts = [] :: [integer()],             % when, in the budget's period (monotonic ms)
    restarted = 0 :: non_neg_integer(),
    %% over several nodes: the nodes of the tree as it stands, in the order
    %% of its sites, and how many times bodies were placed anew
    placed_on = [] :: [node()],
    migrations = 0 :: non_neg_integer(),
    nodes = #{nodes => [node()], peers => []} :: rw_nodes:nodes(),
    %% the counters of the sites on other nodes, from the trees stopped
    %% since, and the sites of the tree as it stands
    remote = #{} :: #{atom() => integer()},
    sites = [] :: [pid()],
    %% the counters of each site of the tree as last read, for a site that
    %% cannot answer any more (its node is lost)
    seen = #{} :: #{pid() => #{atom() => integer()}},
    start = 0 :: non_neg_integer(),           % where this run began, in ticks (its committed work counts from there)
    started :: integer(),                     % monotonic ms
    ended = none :: none | integer(),
    lead = none :: rw_sim:lead(),             % the highest LVT, as last read
    native = false :: boolean()               % the C loops ran on every node of the tree (rw_native:in_use/2)
}).

%% Start a run of Scene under rw_sims_sup, on the nodes it asks for: the
%% peer nodes it starts are the run's, stopped when it ends (they are
%% linked to the caller until the run has taken them over).
-spec start(#scene{}, options()) -> {ok, pid()} | {error, term()}.
start(Scene, Opts) ->
    case rw_nodes:start(maps:get(nodes, Opts, 1), maps:get(schedulers, Opts, undefined)) of
        {ok, Nodes} ->
            case supervisor:start_child(rw_sims_sup, [Scene, Opts#{nodes => Nodes}]) of
                {ok, Run} ->
                    ok = rw_nodes:unlink(Nodes),
                    {ok, Run};
                {error, Reason} ->
                    ok = rw_nodes:stop(Nodes),
                    {error, refused(Reason)}
            end;
        {error, Message} ->
            {error, {nodes, Message}}
    end.

%% Stop it: no process or table is left behind.
-spec stop(pid()) -> ok.
stop(Run) ->
    _ = supervisor:terminate_child(rw_sims_sup, Run),
    ok.

%% Is Pid a live run (a handle's process, not anything else)?
-spec is_run(term()) -> boolean().
is_run(Pid) when is_pid(Pid), node(Pid) =:= node() ->
    case erlang:process_info(Pid, dictionary) of
        {dictionary, D} -> proplists:get_value('$initial_call', D) =:= {?MODULE, init, 1};
        undefined -> false
    end;
is_run(_) -> false.

-spec subscribe(pid(), pid(), none | times | frames, boolean()) -> ok | {error, string()}.
subscribe(Run, Pid, What, Checkpoints) -> gen_server:call(Run, {subscribe, {Pid, What, Checkpoints}}).

%% The caller, named in the acks option, has handled one more frame or
%% time message of Run.
-spec ack(pid()) -> ok.
ack(Run) ->
    Run ! {rw_ack, self()},
    ok.

%% Subscriber Pid waits for the end of Run (true) and reads nothing until
%% then, so Run does not wait for it, or no longer waits for the end
%% (false).
-spec awaiting(pid(), pid(), boolean()) -> ok.
awaiting(Run, Pid, Waiting) -> gen_server:cast(Run, {awaiting, Pid, Waiting}).

-spec status(pid()) -> status().
status(Run) -> gen_server:call(Run, status).

%% GVT in ms: the time of the latest committed sync point (-1 before the
%% first).
-spec gvt(pid()) -> number().
gvt(Run) -> gen_server:call(Run, gvt).

%% The processes of the simulation's tree as it stands, with their names
%% (none between a fault and the restart, or after the end).
-spec processes(pid()) -> [{pid(), rw_sim_sup:who()}].
processes(Run) -> gen_server:call(Run, processes).

%% The nodes of the run (this one first) and the peer nodes it started,
%% with their control processes (peer).
-spec nodes(pid()) -> rw_nodes:nodes().
nodes(Run) -> gen_server:call(Run, nodes).

-spec scene(pid()) -> #scene{}.
scene(Run) -> gen_server:call(Run, scene).

-spec ring(pid()) -> ets:tid().
ring(Run) -> gen_server:call(Run, ring).

%% The counters so far (committed work up to GVT only, wall time frozen
%% at the end), GVT, how far the fastest body is ahead, the status.
-spec stats(pid()) -> map().
stats(Run) -> gen_server:call(Run, stats).

-spec start_link(#scene{}, options()) -> {ok, pid()} | {error, term()}.
start_link(Scene, Opts) -> gen_server:start_link(?MODULE, {Scene, Opts}, []).

%% A run that cannot start stops with {shutdown, Reason}: its caller gets
%% the reason, and nothing is reported as a crash.
-spec init({#scene{}, options()}) -> {ok, #r{}} | {stop, {shutdown, term()}}.
init({Scene, #{nodes := Nodes} = Opts}) ->
    process_flag(trap_exit, true),
    ok = rw_nodes:link(Nodes),
    case schedulers(Opts) of
        ok -> init(Scene, Opts, Nodes);
        {error, Message} -> {stop, {shutdown, {schedulers, Message}}}
    end.

init(Scene, Opts, Nodes) ->
    Flow = atomics:new(1, [{signed, true}]),
    ok = atomics:put(Flow, 1, rw_flow:unbounded()),
    R0 = #r{nodes = Nodes, scene = Scene, opts = maps:merge(#{ring_size => ring_size(Scene)}, Opts),
            buckets = buckets(Scene, Opts),
            records = ets:new(rw_records, [ordered_set, public, {write_concurrency, true}]),
            ring = ets:new(rw_frames, [set, public, {read_concurrency, true}]),
            stats = rw_stats:new(), subs = maps:get(subscribers, Opts, []),
            flow = Flow, allowance = rw_flow:unbounded(),
            unacked = maps:from_list([{Pid, 0} || Pid <- maps:get(acks, Opts, [])]),
            checkpoint = maps:get(from, Opts, none), started = erlang:monotonic_time(millisecond)},
    %% the first tree starts bounded
    R = flow(R0#r{start = restart_tick(R0)}),
    case incarnate(R) of
        {ok, R1} -> {ok, R1};
        {error, Reason} -> ok = rw_nodes:stop(Nodes), _ = release_schedulers(R), {stop, {shutdown, Reason}}
    end.

refused({shutdown, Reason}) -> Reason;
refused(Reason) -> Reason.

%% The frames the ring keeps unless asked otherwise (rw_ring:frames_kept/2):
%% the latest ring_frames (the application's environment, 1024 by
%% default), or fewer for scenes of many bodies.
-define(DEFAULT_RING_FRAMES, 1024).

ring_size(#scene{spheres = Spheres}) -> rw_ring:frames_kept(ring_frames(), length(Spheres)).

ring_frames() ->
    case application:get_env(rigidwarp, ring_frames, ?DEFAULT_RING_FRAMES) of
        N when is_integer(N), N > 0 -> N;
        Bad ->
            logger:warning("rigidwarp: ring_frames must be a positive integer, got ~0p; ~b frames kept",
                           [Bad, ?DEFAULT_RING_FRAMES]),
            ?DEFAULT_RING_FRAMES
    end.

schedulers(#{schedulers := N}) -> rw_schedulers:acquire(N);
schedulers(_) -> ok.

buckets(#scene{buckets = undefined}, Opts) -> maps:get(buckets, Opts, ?DEFAULT_BUCKETS);
buckets(#scene{buckets = B}, Opts) -> maps:get(buckets, Opts, B).

%% Start the simulation's tree from the latest checkpoint (or the scene's
%% start) and watch every process in it.
incarnate(#r{scene = Scene0, checkpoint = Checkpoint, opts = Opts} = R) ->
    Scene = case Checkpoint of
                none -> Scene0;
                _ -> rw_scene:from_checkpoint(Scene0, Checkpoint)
            end,
    Nodes = rw_nodes:alive(R#r.nodes),
    SimOpts = (maps:with(?SIM_KEYS, Opts))#{run => self(), frames => lists:keymember(frames, 2, R#r.subs),
                                            nodes => Nodes, flow => R#r.flow},
    case rw_sim_sup:start_link(Scene, R#r.buckets, #{records => R#r.records, ring => R#r.ring}, R#r.stats, SimOpts) of
        {ok, Sup, Sim, Named} ->
            {ok, R#r{sup = Sup, sim = Sim, sites = [P || {P, {site, _}} <- Named], placed_on = Nodes,
                     native = rw_native:in_use(Sim#sim.native, Nodes),
                     watched = maps:from_list([{erlang:monitor(process, P), {P, Who}} || {P, Who} <- Named])}};
        {error, _} = Error ->
            Error
    end.

%% Stop the simulation's tree (nothing it does matters any more).
teardown(#r{sup = none} = R) -> R;
teardown(#r{sup = Sup, watched = W} = R0) ->
    _ = [erlang:demonitor(Ref, [flush]) || Ref <- maps:keys(W)],
    {Counts, _, _} = site_stats(R0),
    R = R0#r{remote = add_counts(R0#r.remote, Counts), sites = [], seen = #{}},
    ok = rw_sim_parts:stop(Sup),
    receive {'EXIT', Sup, _} -> ok after 0 -> ok end,
    %% (the next tree's bodies publish their LVTs anew: read them afresh)
    R#r{sup = none, watched = #{}, lead = none}.

-spec handle_call(term(), gen_server:from(), #r{}) -> {reply, term(), #r{}}.
handle_call({subscribe, {_, frames, _}}, _From, #r{opts = #{read_frames := false}} = R) ->
    {reply, {error, "this run keeps no frames to read"}, R};
handle_call({subscribe, {Pid, What, _} = Sub}, _From, #r{subs = Subs, sim = Sim} = R) ->
    _ = case What =:= frames andalso not lists:keymember(frames, 2, Subs) andalso R#r.sup =/= none of
            true -> rw_gvt:send_frames(Sim#sim.gvt);
            false -> ok
        end,
    {reply, ok, flow(R#r{subs = [Sub | lists:keydelete(Pid, 1, Subs)]})};
handle_call(status, _From, R) ->
    {reply, R#r.status, R};
handle_call(gvt, _From, R) ->
    {reply, ms(gvt_tick(R), R), R};
handle_call(processes, _From, #r{watched = W} = R) ->
    {reply, maps:values(W), R};
handle_call(nodes, _From, R) ->
    {reply, R#r.nodes, R};
handle_call(scene, _From, R) ->
    {reply, R#r.scene, R};
handle_call(ring, _From, R) ->
    {reply, R#r.ring, R};
handle_call(stats, _From, R) ->
    {Stats, R1} = stats_of(R),
    {reply, Stats, R1}.

-spec handle_cast(term(), #r{}) -> {noreply, #r{}}.
handle_cast({awaiting, Pid, true}, #r{awaiting = A} = R) ->
    {noreply, flow(R#r{awaiting = A#{Pid => true}})};
handle_cast({awaiting, Pid, false}, #r{awaiting = A} = R) ->
    {noreply, flow(R#r{awaiting = maps:remove(Pid, A)})};
handle_cast(_Msg, R) -> {noreply, R}.

-spec handle_info(term(), #r{}) -> {noreply, #r{}}.
handle_info({rw_frame, _Gvt, {frame, Ms, _} = Frame}, R) ->
    {noreply, flow(deliver(Ms, Frame, R))};
handle_info({rw_frame_time, _Gvt, Ms}, R) ->
    {noreply, flow(deliver(Ms, none, R))};
handle_info({rw_ack, Pid}, #r{unacked = U} = R) ->
    case U of
        #{Pid := N} -> {noreply, flow(R#r{unacked = U#{Pid := max(0, N - 1)}})};
        #{} -> {noreply, R}
    end;
handle_info(flow_recheck, R) ->
    {noreply, flow(R#r{recheck = none})};
handle_info({rw_checkpoint, _Gvt, {checkpoint, T, _, _} = C}, #r{checkpoint = Old} = R) ->
    %% a checkpoint from a tree stopped since is committed all the same
    case Old of
        {checkpoint, OldT, _, _} when OldT >= T -> {noreply, R};
        _ ->
            _ = [Pid ! {rw_checkpoint, self(), C} || {Pid, _, true} <- R#r.subs],
            {noreply, maybe_migrate(look_at_sites(R#r{checkpoint = C}))}
    end;
handle_info({rw_done, _Gvt, EndMs}, #r{status = running} = R) ->
    R1 = teardown(R),
    ok = rw_nodes:stop(R1#r.nodes),
    ok = release_schedulers(R1),
    _ = [Pid ! {rw_done, self(), EndMs} || {Pid, _, _} <- R1#r.subs],
    {noreply, R1#r{status = done, ended = erlang:monotonic_time(millisecond)}};
handle_info({rw_stalled, Gvt, Ms, Report}, #r{sim = #sim{gvt = Gvt}, sup = Sup} = R) when Sup =/= none ->
    {noreply, fault(stalled, {gvt_stuck, Ms, Report}, R)};
handle_info({'DOWN', Ref, process, _Pid, Reason}, #r{watched = W} = R) ->
    case maps:find(Ref, W) of
        {ok, {_, Who}} -> {noreply, fault(Who, Reason, R)};
        error -> {noreply, R}
    end;
handle_info({'EXIT', Sup, Reason}, #r{sup = Sup} = R) ->
    {noreply, fault(supervisor, Reason, R)};
handle_info(_Msg, R) ->
    %% messages of a tree stopped since
    {noreply, R}.

-spec terminate(term(), #r{}) -> ok.
terminate(_Reason, R) ->
    _ = teardown(R),
    ok = rw_nodes:stop(R#r.nodes),
    release_schedulers(R).

release_schedulers(#r{opts = Opts}) -> release_schedulers_of(Opts).

release_schedulers_of(#{schedulers := _}) -> rw_schedulers:release();
release_schedulers_of(_) -> ok.

%% A frame GVT has passed, from this tree or one stopped since: to every
%% subscriber, unless it was delivered before a restart.
deliver(Ms, Frame, #r{delivered = Last, scene = Scene} = R) ->
    T = tick(Ms, Scene),
    case T > Last of
        true ->
            Self = self(),
            Sent = [case What of
                        frames when Frame =/= none -> Pid ! {rw_frame, Self, Frame}, Pid;
                        times -> Pid ! {rw_frame_time, Self, Ms}, Pid;
                        _ -> none
                    end || {Pid, What, _} <- R#r.subs],
            Unacked = lists:foldl(fun(Pid, U) when is_map_key(Pid, U) -> maps:update_with(Pid, fun(N) -> N + 1 end, U);
                                     (_, U) -> U
                                  end, R#r.unacked, Sent),
            R#r{delivered = T, unacked = Unacked};
        false ->
            R
    end.

%% Backpressure: the allowance from what the subscribers of frames or
%% times have not handled yet (rw_flow), written where the tree's GVT
%% process and watchdog read it, and the GVT process told when it moves;
%% while GVT is held there, a look again in a few ms.
flow(#r{status = running, scene = #scene{frame = F, spheres = Spheres}, allowance = Old} = R) ->
    Waited = [{What, Backlog} || {Pid, What, _} <- R#r.subs, What =/= none, {ok, Backlog} <- [backlog(Pid, R)]],
    Window = rw_flow:window(length(Spheres), case lists:keymember(frames, 1, Waited) of true -> frames; false -> times end),
    Base = max(R#r.delivered, R#r.start),
    New = rw_flow:allowance(Base, [B || {_, B} <- Waited], Window, F),
    R1 = case rw_flow:move(Old, New, Window, F) of
             true ->
                 ok = atomics:put(R#r.flow, 1, New),
                 _ = [Gvt ! {allow, New} || R#r.sup =/= none, #sim{gvt = Gvt} <- [R#r.sim]],
                 R#r{allowance = New};
             false ->
                 R
         end,
    case rw_flow:held(Base, R1#r.allowance) andalso R1#r.recheck =:= none of
        true -> R1#r{recheck = erlang:send_after(?FLOW_RECHECK_MS, self(), flow_recheck)};
        false -> R1
    end;
flow(R) -> R.

%% The messages subscriber Pid has not handled yet: those it has not
%% acknowledged, or those in its mailbox (which may hold others too); none
%% to wait for if it is gone, on another node or waiting for the end.
backlog(Pid, #r{unacked = U, awaiting = A}) ->
    case is_map_key(Pid, A) orelse node(Pid) =/= node() orelse erlang:process_info(Pid, message_queue_len) of
        true -> none;
        undefined -> none;
        {message_queue_len, Queued} ->
            case U of
                #{Pid := N} -> {ok, N};
                #{} -> {ok, Queued}
            end
    end.

%% A process of the tree died (or GVT stalled): restart from the latest
%% checkpoint, unless the budget is spent.
fault(_Who, _Reason, #r{status = Status} = R) when Status =/= running -> R;
fault(Who, Reason, #r{opts = Opts} = R0) ->
    R = teardown(R0),
    Now = erlang:monotonic_time(millisecond),
    Max = maps:get(max_restarts, Opts, ?DEFAULT_MAX_RESTARTS),
    Period = maps:get(restart_period_ms, Opts, ?DEFAULT_RESTART_PERIOD_MS),
    Recent = [T || T <- R#r.restarts, Now - T < Period],
    case length(Recent) < Max of
        true ->
            From = restart_tick(R),
            logger:warning("rigidwarp: ~ts: ~ts; restarting from the checkpoint at ~p ms (restart ~b of at most ~b "
                           "in ~b ms)", [R#r.scene#scene.name, describe(Who, Reason), ms(From, R), length(Recent) + 1, Max,
                                         Period]),
            ok = rw_ring:truncate(R#r.ring, From),
            ok = rw_commits:keep_only(R#r.records, rw_ring:ticks(R#r.ring)),
            R1 = R#r{restarts = [Now | Recent], restarted = R#r.restarted + 1},
            case incarnate(R1) of
                {ok, R2} -> R2;
                {error, Why} -> crashed(supervisor, Why, R1)
            end;
        false ->
            crashed(Who, Reason, R)
    end.

%% The counters of the sites of the tree (on several nodes): those of the
%% sites on other nodes, and what every node has sent to the others; the
%% highest LVT of their bodies; and the run with the counters read. A site
%% that cannot answer (its node is lost) counts as last read: at the
%% latest checkpoint at least (look_at_sites/1), so that the work redone
%% from there is never counted as done once only, and efficiency stays at
%% or below 1.
site_stats(#r{sites = Sites, seen = Seen} = R) ->
    lists:foldl(fun(Site, {Acc, Lead, Ri}) ->
                        {Counts, L} = try rw_site:stats(Site)
                                      catch exit:_ -> {maps:get(Site, Seen, #{}), 0}
                                      end,
                        Mine = case node(Site) =:= node() of
                                   true -> maps:with([dist_messages, dist_bytes], Counts);
                                   false -> Counts
                               end,
                        {add_counts(Acc, Mine), max(Lead, L), Ri#r{seen = (Ri#r.seen)#{Site => Counts}}}
                end, {#{}, 0, R}, Sites).

%% Read the sites' counters at a checkpoint, the point a restart goes back
%% to: every body's work up to it is counted there.
look_at_sites(#r{sites = []} = R) -> R;
look_at_sites(R) -> element(3, site_stats(R)).

take(Key, Map) ->
    case maps:take(Key, Map) of
        error -> {0, Map};
        Found -> Found
    end.

add_counts(A, B) -> maps:fold(fun(K, V, Acc) -> maps:update_with(K, fun(V0) -> V0 + V end, V, Acc) end, A, B).

%% Over several nodes, bodies live on the node of the slab of space they
%% started in. When a checkpoint finds a tenth of them or more carried into
%% other slabs, the simulation starts again from it, placed anew (as after
%% a fault, but outside the restart budget): a move at a sync point, at the
%% cost of the work done since the checkpoint.
-define(MISPLACED_SHARE, 10).

maybe_migrate(#r{opts = #{migrate := false}} = R) -> R;
maybe_migrate(#r{sim = #sim{placement = Place}, sup = Sup, status = running, placed_on = Nodes,
                 checkpoint = {checkpoint, _, _, States}, scene = #scene{spheres = Spheres}} = R)
  when not is_integer(Place), Sup =/= none ->
    Now = maps:from_list([{Id, node(Pid)} || {Pid, {body, Id}} <- maps:values(R#r.watched)]),
    Misplaced = length([Id || {#sphere{id = Id}, #st{p = P}} <- lists:zip(Spheres, States),
                              maps:get(Id, Now, none) =/= lists:nth(rw_place:site_of(P, Place) + 1, Nodes)]),
    case Misplaced * 100 >= ?MISPLACED_SHARE * length(Spheres) of
        true ->
            R1 = teardown(R),
            ok = rw_ring:truncate(R1#r.ring, restart_tick(R1)),
            ok = rw_commits:keep_only(R1#r.records, rw_ring:ticks(R1#r.ring)),
            case incarnate(R1#r{migrations = R1#r.migrations + 1}) of
                {ok, R2} -> R2;
                {error, Why} -> crashed(supervisor, Why, R1)
            end;
        false ->
            R
    end;
maybe_migrate(R) -> R.

%% Where a restart starts: the latest checkpoint, else the run's start.
restart_tick(#r{checkpoint = {checkpoint, T, _, _}}) -> T;
restart_tick(#r{scene = #scene{start = Start}}) -> Start.

crashed(Who, Reason, R) ->
    logger:error("rigidwarp: ~ts: ~ts; past the restart budget after ~b restarts, the run has crashed at GVT ~p ms",
                 [R#r.scene#scene.name, describe(Who, Reason), R#r.restarted, ms(gvt_tick(R), R)]),
    ok = release_schedulers(R),
    _ = [Pid ! {rw_crashed, self(), Who, Reason} || {Pid, _, _} <- R#r.subs],
    R#r{status = {crashed, Who, Reason}, ended = erlang:monotonic_time(millisecond)}.

%% What died and why, for the log.
describe(stalled, {gvt_stuck, Ms, Report}) ->
    io_lib:format("GVT stuck at ~p ms~n~ts", [Ms, Report]);
describe(Who, Reason) ->
    io_lib:format("~0p died: ~0P", [Who, Reason, 12]).

%% GVT in ticks: the later of the frames delivered and the tree's own GVT.
gvt_tick(#r{sup = none, delivered = D}) -> D;
gvt_tick(#r{sim = #sim{gvt_now = Now}, delivered = D}) -> max(D, atomics:get(Now, 1)).

ms(T, #r{scene = Scene}) -> rw_scene:ms(Scene, T).

tick(Ms, #scene{tick_us = U}) -> round(Ms * 1000 / U).

stats_of(#r{scene = #scene{spheres = Spheres, substep = Dt, duration = End, stride = Asked}, stats = Ref,
            sim = Sim, started = T0, start = Start} = R) ->
    Profile = case Sim of #sim{profile = P} -> P; undefined -> false end,
    %% GVT before the counters: a body counts its work before it commits
    %% it, so the work up to G is all counted by then
    G = gvt_tick(R),
    {SiteCounts, SiteLead, R0} = site_stats(R),
    Raw = add_counts(add_counts(rw_stats:read(Ref, Profile), R#r.remote), SiteCounts),
    N = length(Spheres),
    Committed = N * (max(G, Start) - Start) div Dt,
    Computed = maps:get(computed_substeps, Raw),
    Wall = max(1, case R#r.ended of none -> erlang:monotonic_time(millisecond); E -> E end - T0),
    {Lead, LeadRead} = case {R#r.sup, Sim} of
                           {none, _} -> {G, R#r.lead};
                           {_, #sim{lvts = Lvts, placement = Place}} when is_integer(Place) ->
                               rw_sim:lead(Lvts, all, erlang:monotonic_time(millisecond), R#r.lead);
                           {_, #sim{}} ->
                               %% over several nodes, each site knows its own bodies'
                               {SiteLead, R#r.lead}
                       end,
    GvtMs = ms(G, R),
    SimS = max(1, GvtMs - ms(Start, R)) / 1000,
    {Messages, Raw1} = take(dist_messages, Raw),
    {Bytes, Raw2} = take(dist_bytes, Raw1),
    Nodes = length(maps:get(nodes, R#r.nodes)),
    Crossing = case Nodes of
                   1 -> #{};
                   _ -> #{cross_node_messages => Messages, cross_node_bytes => Bytes, migrations => R#r.migrations,
                          cross_node_messages_per_s => Messages / SimS, cross_node_bytes_per_s => Bytes / SimS}
               end,
    {(maps:merge(Raw2, Crossing))#{
         nodes => Nodes,
         rollbacks => maps:get(primary_rollbacks, Raw) + maps:get(secondary_rollbacks, Raw),
         committed_substeps => Committed,
         efficiency => case Computed of 0 -> 1.0; _ -> Committed / Computed end,
         gvt => GvtMs, start_ms => ms(Start, R), end_ms => ms(End, R), max_lvt => ms(max(Lead, G), R), wall_ms => Wall,
         realtime_factor => max(0, GvtMs - ms(Start, R)) / Wall,
         status => case R#r.status of {crashed, _, _} -> crashed; Status -> Status end,
         restarts => R#r.restarted, native => R#r.native,
         %% the scene's stride, and the one the engine runs with under the
         %% run's memory budget for speculation (rw_speculation); throttled
         %% also when the memory guard held bodies back
         stride_ms => ms(Asked, R), effective_stride_ms => ms(stride(Sim, Asked), R),
         throttled => stride(Sim, Asked) < Asked orelse maps:get(memory_holds, Raw) > 0}, R0#r{lead = LeadRead}}.

stride(#sim{scene = #scene{stride = Stride}}, _Asked) -> Stride;
stride(undefined, Asked) -> Asked.
