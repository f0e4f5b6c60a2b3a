%% The supervision tree of one incarnation of a Time Warp simulation.
%%
%%   rw_sims_sup (simple_one_for_one, temporary children)
%%   `-- rw_run              the run: owns the records and the frame ring, keeps
%%       |                   the latest checkpoint, restarts the tree after a fault
%%       `-- rw_sim_sup (rest_for_one, no restarts)
%%           |-- rw_sim_tables    owns the working ETS tables (counts, procs, owners, met)
%%           |-- buckets          one_for_all: the fixed pool {bucket, 0..N-1} (rw_bucket)
%%           |-- rw_gvt           GVT counter, frames into the ring, regroup plans
%%           |-- rw_watchdog      says who holds GVT back when it stalls
%%           `-- bodies           simple_one_for_one: one rw_body per sphere
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
%% before the watchdog speaks.
-type options() :: #{run => pid(), frames => boolean(), ring_size => pos_integer(),
                     checkpoint_ms => non_neg_integer(), watchdog_ms => pos_integer(), atom() => term()}.
%% A process of the simulation, as a fault report names it.
-type who() :: tables | {bucket, non_neg_integer()} | gvt | watchdog | {body, binary()}.

%% Start the tree of a simulation of Scene (from its start time) with
%% NBuckets buckets, linked to the caller, over the run's records and ring
%% and its counters: the supervisor, the context and every process in it
%% with its name. Its bodies are told to go once every one of them exists.
-spec start_link(#scene{}, pos_integer(), #{records := ets:tid(), ring := ets:tid()}, rw_stats:counters(),
                 options()) -> {ok, pid(), #sim{}, [{pid(), who()}]} | {error, term()}.
start_link(#scene{model = M, substep = Dt, spheres = Spheres, initial = Initial} = Scene, NBuckets, RunTables, Stats,
           Opts) ->
    {ok, Sup} = supervisor:start_link(?MODULE, sim),
    try
        {ok, TablesPid} = child(Sup, worker(tables, rw_sim_tables, [])),
        Tables = maps:merge(rw_sim_tables:tables(TablesPid), RunTables),
        Profile = case maps:get(profile, Opts, false) of true -> Stats; false -> undefined end,
        {ok, BucketSup} = child(Sup, #{id => buckets, type => supervisor, restart => permanent,
                                      start => {supervisor, start_link, [?MODULE, {buckets, M, Dt, NBuckets, Profile}]}}),
        Buckets = lists:sort([{I, P} || {{bucket, I}, P, _, _} <- supervisor:which_children(BucketSup)]),
        Sim0 = rw_sim:new(Scene, Tables, list_to_tuple([P || {_, P} <- Buckets]), Stats, Opts),
        {ok, Gvt} = child(Sup, worker(gvt, rw_gvt, [Sim0, maps:with([run, frames, ring_size, checkpoint_ms], Opts)])),
        Sim = Sim0#sim{gvt = Gvt},
        {ok, Watchdog} = child(Sup, worker(watchdog, rw_watchdog, [Sim, maps:get(run, Opts, undefined),
                                                                   maps:get(watchdog_ms, Opts, 10000)])),
        {ok, BodySup} = child(Sup, #{id => bodies, type => supervisor, restart => permanent,
                                    start => {supervisor, start_link, [?MODULE, bodies]}}),
        BodySim = rw_sim:for_bodies(Sim),
        Bodies = [begin
                      {ok, Pid} = supervisor:start_child(BodySup, [BodySim, Sphere, St]),
                      {Idx, Id, Pid}
                  end || {#sphere{idx = Idx, id = Id} = Sphere, St} <- lists:zip(Spheres, Initial)],
        true = ets:insert(Sim#sim.procs, [{Idx, Pid} || {Idx, _, Pid} <- Bodies]),
        _ = [Pid ! go || {_, _, Pid} <- Bodies],
        Named = [{TablesPid, tables}, {Gvt, gvt}, {Watchdog, watchdog}]
            ++ [{P, {bucket, I}} || {I, P} <- Buckets] ++ [{Pid, {body, Id}} || {_, Id, Pid} <- Bodies],
        {ok, Sup, Sim, Named}
    catch
        Class:Reason ->
            unlink(Sup),
            exit(Sup, kill),
            {error, {Class, Reason}}
    end.

child(Sup, Spec) -> supervisor:start_child(Sup, Spec).

worker(Id, Mod, Args) ->
    #{id => Id, start => {Mod, start_link, Args}, restart => permanent, shutdown => 1000, type => worker}.

-spec init(sim | {buckets, #model{}, pos_integer(), pos_integer(), rw_stats:counters() | undefined} | bodies) ->
          {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init(sim) ->
    {ok, {#{strategy => rest_for_one, intensity => 0, period => 1}, []}};
init({buckets, M, Dt, N, Profile}) ->
    {ok, {#{strategy => one_for_all, intensity => 0, period => 1},
          [#{id => {bucket, I}, start => {rw_bucket, start_link, [M, Dt, Profile]}, restart => permanent,
             shutdown => 1000} || I <- lists:seq(0, N - 1)]}};
init(bodies) ->
    {ok, {#{strategy => simple_one_for_one, intensity => 0, period => 1},
          [#{id => body, start => {rw_body, start_link, []}, restart => temporary, shutdown => 1000}]}}.
