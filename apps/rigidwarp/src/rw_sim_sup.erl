%% The supervision tree of one Time Warp simulation.
%%
%%   rw_sims_sup (simple_one_for_one, temporary children)
%%   `-- rw_sim_sup (rest_for_one, no restarts)
%%       |-- rw_sim_tables    owns the ETS tables: records, counts, frame ring
%%       |-- rw_gvt           GVT counter, frames, watchdog
%%       |-- rw_bucket_sup    one_for_all: the fixed pool {bucket, 0..N-1}
%%       `-- rw_body_sup      simple_one_for_one: one rw_body per sphere
%%
%% A simulation's processes share state that no single process can rebuild
%% (a body's timeline, a bucket's states and locks), so any crash ends the
%% simulation: intensity 0, and the runner reports the failure. Every
%% committed frame is self-sufficient (full state of every body), so a later
%% restart can resume from the latest frame in the ring.
-module(rw_sim_sup).
-behaviour(supervisor).
-include("rigidwarp.hrl").
-export([start_link/2, init/1, children/1]).

-spec start_link(#scene{}, pos_integer()) -> {ok, pid()} | {error, term()}.
start_link(Scene, Buckets) -> supervisor:start_link(?MODULE, {sim, Scene, Buckets}).

-spec init({sim, #scene{}, pos_integer()} | {buckets, #model{}, pos_integer(), pos_integer()} | bodies) ->
          {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init({sim, #scene{model = M, substep = Dt}, Buckets}) ->
    Worker = fun(Id, Mod, Args) -> #{id => Id, start => {Mod, start_link, Args}, restart => permanent,
                                     shutdown => 1000, type => worker} end,
    Sup = fun(Id, Args) -> #{id => Id, start => {supervisor, start_link, [?MODULE, Args]},
                             restart => permanent, type => supervisor} end,
    {ok, {#{strategy => rest_for_one, intensity => 0, period => 1},
          [Worker(tables, rw_sim_tables, []),
           Worker(gvt, rw_gvt, []),
           Sup(buckets, {buckets, M, Dt, Buckets}),
           Sup(bodies, bodies)]}};
init({buckets, M, Dt, N}) ->
    {ok, {#{strategy => one_for_all, intensity => 0, period => 1},
          [#{id => {bucket, I}, start => {rw_bucket, start_link, [M, Dt, I]}, restart => permanent,
             shutdown => 1000} || I <- lists:seq(0, N - 1)]}};
init(bodies) ->
    {ok, {#{strategy => simple_one_for_one, intensity => 0, period => 1},
          [#{id => body, start => {rw_body, start_link, []}, restart => temporary, shutdown => 1000}]}}.

%% The pids of a running simulation's parts.
-spec children(pid()) -> #{tables := pid(), gvt := pid(), buckets := tuple(), bodies := pid()}.
children(Sup) ->
    Kids = supervisor:which_children(Sup),
    {_, Tables, _, _} = lists:keyfind(tables, 1, Kids),
    {_, Gvt, _, _} = lists:keyfind(gvt, 1, Kids),
    {_, BucketSup, _, _} = lists:keyfind(buckets, 1, Kids),
    {_, BodySup, _, _} = lists:keyfind(bodies, 1, Kids),
    Buckets = lists:sort([{I, P} || {{bucket, I}, P, _, _} <- supervisor:which_children(BucketSup)]),
    #{tables => Tables, gvt => Gvt, buckets => list_to_tuple([P || {_, P} <- Buckets]), bodies => BodySup}.
