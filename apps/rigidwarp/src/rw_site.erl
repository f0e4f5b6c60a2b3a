%% One node's share of a simulation over several nodes: a process on that
%% node, linked to the simulation's supervisor (rw_sim_sup) on the node the
%% run was started from, holding the node's own tree:
%%
%%   rw_site
%%   `-- site supervisor (rest_for_one, no restarts)
%%       |-- rw_sim_tables   this node's commit counts, owners, processes, met
%%       |-- buckets         this node's share of the TVHT's buckets
%%       |-- rw_gvt_site     this node's share of GVT
%%       `-- bodies          the bodies placed on this node
%%
%% Everything a body reads or writes besides messages is on its own node:
%% the tables, the atomics of GVT and LVTs, the counters. The site starts
%% in two steps, as the whole simulation's buckets must exist before any
%% body does: start_link/2 starts the tables and the buckets, bodies/4 the
%% rest. When the simulation's supervisor stops it (or its node goes
%% away), it stops its tree first.
-module(rw_site).
-include("rigidwarp.hrl").
-export([start_link/2, bodies/4, stats/1]).
-export([init/2]).
-export_type([options/0]).

%% The buckets to start (per: how many), their model and substep, the
%% bodies they are for (about as many as the site will hold), and whether
%% to profile; stats: the run's counters, when the site is on the run's
%% node (elsewhere the site has its own); native: whether the run uses the
%% C loops (where the library is loaded on the site's node).
-type options() :: #{model := #model{}, dt := pos_integer(), per := pos_integer(), bodies := non_neg_integer(),
                     profile := boolean(), stats := rw_stats:counters() | undefined, native := boolean()}.

-define(START_MS, 60000).

%% Start the site on Node, linked to the caller: its tables and buckets.
-spec start_link(node(), options()) -> {ok, pid(), [pid()]} | {error, term()}.
start_link(Node, Opts) ->
    Pid = proc_lib:spawn_link(Node, ?MODULE, init, [self(), Opts]),
    receive
        {Pid, buckets, Buckets} -> {ok, Pid, Buckets};
        {'EXIT', Pid, Reason} -> {error, {site, Node, Reason}}
    after ?START_MS ->
            unlink(Pid),
            exit(Pid, kill),
            {error, {site, Node, timeout}}
    end.

%% Start the site's GVT process and its bodies (Spheres with their states
%% Initial) in the context Sim, reporting to the run's GVT process RunGvt:
%% the site's GVT process and {Idx, Id, Pid} of every body.
-spec bodies(pid(), #sim{}, [{#sphere{}, #st{}}], pid()) -> {pid(), [{non_neg_integer(), binary(), pid()}]}.
bodies(Site, Sim, Bodies, RunGvt) -> call(Site, {bodies, Sim, Bodies, RunGvt}).

%% The site's counters (rw_stats names) and what this node has sent to
%% other nodes since the site started (dist_messages, dist_bytes); and the
%% highest LVT of its bodies (0 before they start).
-spec stats(pid()) -> {#{atom() => integer()}, non_neg_integer()}.
stats(Site) -> call(Site, stats).

call(Site, Req) ->
    MRef = erlang:monitor(process, Site),
    Site ! {call, self(), MRef, Req},
    receive
        {MRef, Reply} ->
            erlang:demonitor(MRef, [flush]),
            Reply;
        {'DOWN', MRef, process, Site, Reason} ->
            exit({site_down, Reason})
    after ?START_MS ->
            exit(timeout)
    end.

-record(site, {
    parent :: pid(),
    sup :: pid(),
    tables :: map(),
    buckets :: [pid()],
    stats :: rw_stats:counters(),
    profile :: boolean(),
    sent :: {non_neg_integer(), non_neg_integer()},
    lvts = none :: none | {atomics:atomics_ref(), [non_neg_integer()]},  % its bodies' LVTs, once they exist
    lead = none :: rw_sim:lead()                                         % their highest, as last read
}).

-spec init(pid(), options()) -> no_return().
init(Parent, #{model := M, dt := Dt, per := Per, bodies := Bodies, profile := Profile, stats := Stats0, native := Native}) ->
    process_flag(trap_exit, true),
    Stats = case Stats0 of undefined -> rw_stats:new(); _ -> Stats0 end,
    {ok, Sup} = supervisor:start_link(rw_sim_parts, sim),
    {ok, TablesPid} = supervisor:start_child(Sup, rw_sim_parts:worker(tables, rw_sim_tables, [])),
    Records = ets:new(rw_site_records, [ordered_set, public, {write_concurrency, true}]),
    Tables = (rw_sim_tables:tables(TablesPid))#{records => Records},
    BucketProfile = case Profile of true -> Stats; false -> undefined end,
    {ok, BucketSup} = supervisor:start_child(Sup, rw_sim_parts:bucket_pool(M, Dt, Per, BucketProfile, undefined, Bodies,
                                                                                Native)),
    Buckets = [P || {_, P} <- lists:sort([{I, P} || {{bucket, I}, P, _, _} <- supervisor:which_children(BucketSup)])],
    Parent ! {self(), buckets, Buckets},
    loop(#site{parent = Parent, sup = Sup, tables = Tables, buckets = Buckets, stats = Stats, profile = Profile,
               sent = dist_sent()}).

loop(#site{parent = Parent, sup = Sup} = S) ->
    receive
        {call, From, Ref, Req} ->
            {Reply, S1} = handle(Req, S),
            From ! {Ref, Reply},
            loop(S1);
        {'EXIT', Parent, Reason} ->
            ok = rw_sim_parts:stop(Sup),
            exit(Reason);
        {'EXIT', Sup, Reason} ->
            exit(Reason);
        _ ->
            loop(S)
    end.

handle({bodies, Sim0, Bodies, RunGvt}, #site{sup = Sup, tables = Tables, buckets = Buckets} = S) ->
    Sim1 = rw_sim:for_site(Sim0, [Idx || {#sphere{idx = Idx}, _} <- Bodies], Tables, S#site.stats),
    {ok, Gvt} = supervisor:start_child(Sup, rw_sim_parts:worker(gvt, rw_gvt_site, [Sim1, RunGvt, Buckets])),
    Sim = Sim1#sim{gvt = Gvt},
    {ok, BodySup} = supervisor:start_child(Sup, rw_sim_parts:body_pool()),
    Started = rw_sim_parts:start_bodies(BodySup, rw_sim:for_bodies(Sim), Bodies),
    {{Gvt, Started}, S#site{lvts = {Sim#sim.lvts, [Idx || {#sphere{idx = Idx}, _} <- Bodies]}}};
handle(stats, #site{stats = Stats, profile = Profile, sent = {N0, B0}} = S) ->
    {N, B} = dist_sent(),
    {Lead, LeadRead} = case S#site.lvts of
                           none -> {0, S#site.lead};
                           {Lvts, Idxs} -> rw_sim:lead(Lvts, Idxs, erlang:monotonic_time(millisecond), S#site.lead)
                       end,
    {{(rw_stats:read(Stats, Profile))#{dist_messages => N - N0, dist_bytes => B - B0}, Lead}, S#site{lead = LeadRead}}.

%% What this node has sent over its distribution connections: messages
%% (packets) and bytes.
dist_sent() ->
    lists:foldl(fun({_Node, Port}, {N, B}) when is_port(Port) ->
                        case inet:getstat(Port, [send_cnt, send_oct]) of
                            {ok, [{send_cnt, Cnt}, {send_oct, Oct}]} -> {N + Cnt, B + Oct};
                            {ok, Stat} -> {N + proplists:get_value(send_cnt, Stat, 0), B + proplists:get_value(send_oct, Stat, 0)};
                            {error, _} -> {N, B}
                        end;
                   (_, Acc) -> Acc
                end, {0, 0}, erlang:system_info(dist_ctrl)).
