%% The supervision tree of one incarnation of a Time Warp simulation.
%%
%%   rw_sims_sup (simple_one_for_one, temporary children)
%%   `-- rw_run              the run: owns the records and the frame ring, keeps
%%       |                   the latest checkpoint, restarts the tree after a fault
%%       `-- rw_sim_sup (rest_for_one, no restarts)
%%           |-- rw_sim_tables    owns the working ETS tables (counts, procs, owners, met)
%%           |-- buckets          one_for_all: the fixed pool {bucket, 0..N-1} (rw_bucket)
%%           |-- rw_sweeper       forgets the records the GVT process is done with
%%           |-- rw_gvt           GVT counter, frames into the ring, regroup plans
%%           |-- rw_watchdog      says who holds GVT back when it stalls
%%           |-- bodies           simple_one_for_one: one rw_body per sphere
%%           `-- rw_memory_guard  holds bodies back when the run outgrows its
%%                                memory budget (on one node)
%%
%% Each child depends on those before it, and gets the simulation's
%% context (#sim{}, rw_sim) as a start argument: start_link/5 adds them in
%% this order, building the context once the tables and buckets exist.
%%
%% The processes of a simulation share state that no single process can
%% rebuild (an entity's timeline, a bucket's states and locks), so nothing
%% here restarts on its own: the run watches every process and, when one
%% dies, stops this tree and starts another from the latest checkpoint.
-module(rw_sim_sup).
-behaviour(supervisor).
-include("rigidwarp.hrl").
-export([start_link/5, init/1]).
-export_type([options/0, who/0]).

%% The context's options (rw_sim), and run: the rw_run process, told of
%% frames, checkpoints, the end and stalls; frames, ring_size,
%% checkpoint_ms (rw_gvt); watchdog_ms: how long GVT may stand still
%% before the watchdog speaks; flow: the run's allowance (rw_flow), which
%% the GVT process keeps to and the watchdog knows of; native: whether the run uses the C loops
%% (rw_native:default/0 unless given).
-type options() :: #{nodes => [node()], run => pid(), frames => boolean(), ring_size => pos_integer(),
                     checkpoint_ms => non_neg_integer(), watchdog_ms => pos_integer(), flow => atomics:atomics_ref(),
                     atom() => term()}.
%% A process of the simulation, as a fault report names it.
-type who() :: tables | {bucket, non_neg_integer()} | gvt | sweeper | watchdog | {body, binary()} | memory_guard
             | {site, node()} | {site_gvt, node()}.

%% Start the tree of a simulation of Scene (from its start time) with
%% NBuckets buckets, linked to the caller, over the run's records and ring
%% and its counters: the supervisor, the context and every process in it
%% with its name. Its bodies are told to go once every one of them exists.
-spec start_link(#scene{}, pos_integer(), #{records := ets:tid(), ring := ets:tid()}, rw_stats:counters(),
                 options()) -> {ok, pid(), #sim{}, [{pid(), who()}]} | {error, term()}.
start_link(Scene, NBuckets, RunTables, Stats, Opts0) ->
    Opts = maps:merge(#{native => rw_native:default()}, Opts0),
    {ok, Sup} = supervisor:start_link(?MODULE, sim),
    try
        {ok, TablesPid} = child(Sup, rw_sim_parts:worker(tables, rw_sim_tables, [])),
        Tables = maps:merge(rw_sim_tables:tables(TablesPid), RunTables),
        {Sim, Named} = case maps:get(nodes, Opts, [node()]) of
                           [Node] when Node =:= node() -> one_node(Sup, Scene, NBuckets, Tables, Stats, Opts);
                           Nodes -> nodes(Sup, Nodes, Scene, NBuckets, Tables, Stats, Opts)
                       end,
        {ok, Sup, Sim, [{TablesPid, tables} | Named]}
    catch
        Class:Reason ->
            unlink(Sup),
            exit(Sup, kill),
            {error, {Class, Reason}}
    end.

one_node(Sup, #scene{model = M, substep = Dt, spheres = Spheres, initial = Initial} = Scene, NBuckets, Tables, Stats,
         Opts) ->
    Profile = case maps:get(profile, Opts, false) of true -> Stats; false -> undefined end,
    {ok, BucketSup} = child(Sup, rw_sim_parts:bucket_pool(M, Dt, NBuckets, Profile, maps:get(trace, Opts, undefined),
                                                              length(Spheres), maps:get(native, Opts))),
    Buckets = lists:sort([{I, P} || {{bucket, I}, P, _, _} <- supervisor:which_children(BucketSup)]),
    Sim0 = rw_sim:new(Scene, Tables, list_to_tuple([P || {_, P} <- Buckets]), Stats, Opts),
    {Sweeper, Gvt} = start_gvt(Sup, Sim0, Tables, Opts),
    Sim = Sim0#sim{gvt = Gvt},
    {ok, Watchdog} = child(Sup, watchdog(Sim, Opts)),
    {ok, BodySup} = child(Sup, rw_sim_parts:body_pool()),
    Bodies = rw_sim_parts:start_bodies(BodySup, rw_sim:for_bodies(Sim), lists:zip(Spheres, Initial)),
    %% (started before the bodies go: it measures the memory the run
    %% holds from there)
    {ok, Guard} = child(Sup, rw_sim_parts:worker(memory_guard, rw_memory_guard,
                                                 [Sim, [Pid || {_, _, Pid} <- Bodies] ++ [P || {_, P} <- Buckets],
                                                  rw_speculation:budget_bytes(Opts)])),
    _ = [Pid ! go || {_, _, Pid} <- Bodies],
    {Sim, [{Gvt, gvt}, {Sweeper, sweeper}, {Watchdog, watchdog}, {Guard, memory_guard}]
          ++ [{P, {bucket, I}} || {I, P} <- Buckets] ++ [{Pid, {body, Id}} || {_, Id, Pid} <- Bodies]}.

%% Over several nodes: a site on each (rw_site), the bodies and buckets
%% placed by space (rw_place), this node's GVT process deciding from the
%% sites' reports (rw_gvt, rw_gvt_site).
nodes(Sup, Nodes, #scene{model = M, substep = Dt, spheres = Spheres, initial = Initial, cell_size = Cell} = Scene,
      NBuckets, Tables, Stats, Opts) ->
    K = length(Nodes),
    Per = max(1, NBuckets div K),
    Place = rw_place:new([P || #st{p = P} <- Initial], K, Per, Cell),
    Profile = maps:get(profile, Opts, false),
    Sites = [begin
                 SiteStats = case Node =:= node() of true -> Stats; false -> undefined end,
                 SiteOpts = #{model => M, dt => Dt, per => Per, bodies => length(Spheres) div K, profile => Profile,
                              stats => SiteStats, native => maps:get(native, Opts)},
                 {ok, Pid, Buckets} = child(Sup, #{id => {site, I}, start => {rw_site, start_link, [Node, SiteOpts]},
                                                   restart => permanent, shutdown => 10000, type => worker}),
                 {I, Node, Pid, Buckets}
             end || {I, Node} <- lists:zip(lists:seq(0, K - 1), Nodes)],
    AllBuckets = list_to_tuple(lists:append([B || {_, _, _, B} <- Sites])),
    %% (every record is kept, and every frame time is a sync point: each site
    %% sends the records of the sync points the run needs, rw_gvt_site)
    Sim0 = (rw_sim:new(Scene, Tables, AllBuckets, Stats, Opts#{read_frames => true}))#sim{placement = Place},
    {Sweeper, Gvt} = start_gvt(Sup, Sim0, Tables, Opts),
    Sim = Sim0#sim{gvt = Gvt},
    {ok, Watchdog} = child(Sup, watchdog(Sim, Opts)),
    Shares = rw_place:split([{{Sphere, St}, P} || {Sphere, #st{p = P} = St} <- lists:zip(Spheres, Initial)], Place),
    Started = [{I, rw_site:bodies(Pid, rw_sim:portable(Sim), Share, Gvt)}
               || {{I, _, Pid, _}, Share} <- lists:zip(Sites, Shares)],
    Bodies = lists:append([B || {_, {_, B}} <- Started]),
    true = ets:insert(Sim#sim.procs, [{Idx, Pid} || {Idx, _, Pid} <- Bodies]),
    SiteOf = maps:from_list([{Idx, I} || {I, {_, B}} <- Started, {Idx, _, _} <- B]),
    GvtOf = maps:from_list([{Pid, SiteGvt} || {_, {SiteGvt, B}} <- Started, {_, _, Pid} <- B]),
    Voters = [SiteGvt || {_, {SiteGvt, B}} <- Started, B =/= []],
    ok = rw_gvt:sites(Gvt, [SiteGvt || {_, {SiteGvt, _}} <- Started], {SiteOf, GvtOf, Voters}),
    _ = [Pid ! go || {_, _, Pid} <- Bodies],
    BucketNames = lists:append([[{P, {bucket, I * Per + J}} || {J, P} <- lists:zip(lists:seq(0, length(B) - 1), B)]
                                || {I, _, _, B} <- Sites]),
    {Sim, [{Gvt, gvt}, {Sweeper, sweeper}, {Watchdog, watchdog}]
          ++ [{Pid, {site, Node}} || {_, Node, Pid, _} <- Sites]
          ++ [{SiteGvt, {site_gvt, node(SiteGvt)}} || {_, {SiteGvt, _}} <- Started]
          ++ BucketNames ++ [{Pid, {body, Id}} || {_, Id, Pid} <- Bodies]}.

child(Sup, Spec) -> supervisor:start_child(Sup, Spec).

watchdog(Sim, Opts) ->
    rw_sim_parts:worker(watchdog, rw_watchdog, [Sim, maps:get(run, Opts, undefined), maps:get(watchdog_ms, Opts, 10000),
                                                maps:get(flow, Opts, undefined)]).

%% The sweeper, then the GVT process that hands it the records it is done
%% with.
start_gvt(Sup, Sim, Tables, Opts) ->
    {ok, Sweeper} = child(Sup, rw_sim_parts:worker(sweeper, rw_sweeper, [maps:get(records, Tables)])),
    GvtOpts = (maps:with([run, frames, ring_size, checkpoint_ms, flow], Opts))#{sweeper => Sweeper},
    {ok, Gvt} = child(Sup, rw_sim_parts:worker(gvt, rw_gvt, [Sim, GvtOpts])),
    {Sweeper, Gvt}.

-spec init(sim) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init(sim) -> rw_sim_parts:init(sim).
