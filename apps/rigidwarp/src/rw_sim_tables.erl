%% Owns the working ETS tables of one simulation and does nothing else:
%% the counts of commits, the processes, who steps which body and the pairs
%% that met. (The committed records and the frame ring belong to the run,
%% rw_run, and outlive every restart.)
-module(rw_sim_tables).
-behaviour(gen_server).
-export([start_link/0, tables/1]).
-export([init/1, handle_call/3, handle_cast/2]).

-type tables() :: #{counts := ets:tid(), owners := ets:tid(), procs := ets:tid(), met := ets:tid()}.
-export_type([tables/0]).

-spec start_link() -> {ok, pid()}.
start_link() -> gen_server:start_link(?MODULE, [], []).

-spec tables(pid()) -> tables().
tables(Pid) -> gen_server:call(Pid, tables).

-spec init([]) -> {ok, tables()}.
init([]) ->
    {ok, #{counts => ets:new(rw_counts, [set, public, {write_concurrency, true}]),
           procs => ets:new(rw_procs, [set, public, {read_concurrency, true}]),
           owners => ets:new(rw_owners, [set, public, {read_concurrency, true}, {write_concurrency, true}]),
           met => ets:new(rw_met, [set, public, {write_concurrency, true}])}}.

-spec handle_call(tables, gen_server:from(), tables()) -> {reply, tables(), tables()}.
handle_call(tables, _From, Tabs) -> {reply, Tabs, Tabs}.

-spec handle_cast(term(), tables()) -> {noreply, tables()}.
handle_cast(_Msg, Tabs) -> {noreply, Tabs}.
