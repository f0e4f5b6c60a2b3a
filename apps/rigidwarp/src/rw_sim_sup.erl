%% The supervision tree of one Time Warp simulation.
%%
%%   rw_sims_sup (simple_one_for_one, temporary children)
%%   `-- rw_sim_sup (rest_for_one, no restarts)
%%       |-- rw_sim_tables    owns the ETS tables (rw_commits, rw_ring, owners, met)
%%       |-- buckets          one_for_all: the fixed pool {bucket, 0..N-1} (rw_bucket)
%%       |-- rw_gvt           GVT counter, frames into the ring, regroup plans
%%       |-- rw_watchdog      says who holds GVT back when it stalls
%%       `-- bodies           simple_one_for_one: one rw_body per sphere
%%
%% Each child depends on those before it, and gets the simulation's
%% context (#sim{}, rw_sim) as a start argument: start/3 adds them in this
%% order, building the context once the tables and buckets exist.
%%
%% A simulation's processes share state that no single process can rebuild
%% (an entity's timeline, a bucket's states and locks), so any crash ends
%% the simulation: intensity 0, and the runner reports the failure.
-module(rw_sim_sup).
-behaviour(supervisor).
-include("rigidwarp.hrl").
-export([start_link/0, start/3, init/1]).
-export_type([options/0]).

%% The context's options (rw_sim), and owner: told {rw_done, ...} and
%% {rw_stalled, ...}; subscribers, ring_size (rw_gvt); watchdog_ms: how
%% long GVT may stand still before the watchdog speaks.
-type options() :: #{owner => pid(), subscribers => [{pid(), frames | times}], ring_size => pos_integer(),
                     watchdog_ms => pos_integer(), atom() => term()}.

-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() -> supervisor:start_link(?MODULE, sim).

%% Start a simulation of Scene with NBuckets buckets under rw_sims_sup:
%% its supervisor and context. Its bodies are told to go once every one of
%% them exists.
-spec start(#scene{}, pos_integer(), options()) -> {ok, pid(), #sim{}} | {error, term()}.
start(#scene{model = M, substep = Dt, spheres = Spheres, initial = Initial} = Scene, NBuckets, Opts) ->
    case supervisor:start_child(rw_sims_sup, []) of
        {ok, Sup} ->
            try
                {ok, TablesPid} = child(Sup, worker(tables, rw_sim_tables, [])),
                Tables = rw_sim_tables:tables(TablesPid),
                Stats = rw_stats:new(),
                Profile = case maps:get(profile, Opts, false) of true -> Stats; false -> undefined end,
                {ok, BucketSup} = child(Sup, #{id => buckets, type => supervisor, restart => permanent,
                                              start => {supervisor, start_link, [?MODULE, {buckets, M, Dt, NBuckets, Profile}]}}),
                Buckets = lists:sort([{I, P} || {{bucket, I}, P, _, _} <- supervisor:which_children(BucketSup)]),
                Sim0 = rw_sim:new(Scene, Tables, list_to_tuple([P || {_, P} <- Buckets]), Stats, Opts),
                {ok, Gvt} = child(Sup, worker(gvt, rw_gvt, [Sim0, maps:with([owner, subscribers, ring_size], Opts)])),
                Sim = Sim0#sim{gvt = Gvt},
                {ok, _} = child(Sup, worker(watchdog, rw_watchdog, [Sim, maps:get(owner, Opts, undefined),
                                                                     maps:get(watchdog_ms, Opts, 10000)])),
                {ok, BodySup} = child(Sup, #{id => bodies, type => supervisor, restart => permanent,
                                            start => {supervisor, start_link, [?MODULE, bodies]}}),
                BodySim = rw_sim:for_bodies(Sim),
                Bodies = [begin
                              {ok, Pid} = supervisor:start_child(BodySup, [BodySim, Sphere, St]),
                              {Idx, Pid}
                          end || {#sphere{idx = Idx} = Sphere, St} <- lists:zip(Spheres, Initial)],
                true = ets:insert(Sim#sim.procs, Bodies),
                _ = [Pid ! go || {_, Pid} <- Bodies],
                {ok, Sup, Sim}
            catch
                Class:Reason ->
                    _ = supervisor:terminate_child(rw_sims_sup, Sup),
                    {error, {Class, Reason}}
            end;
        {error, _} = Error ->
            Error
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
