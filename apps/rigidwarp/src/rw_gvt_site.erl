%% The GVT process of one node's site, in a simulation over several nodes:
%% it computes this node's share of GVT and carries GVT out on this node.
%% The GVT process of the run (rw_gvt, on the node the run was started
%% from) decides.
%%
%% Entities commit into this node's tables (rw_commits), and the commit
%% that completes a sync point here tells this process, which tells the
%% run's GVT process: {site_complete, Site, [{T, Withdrawals}]}. Once every
%% site has said so of T, the run's GVT process asks every site to confirm
%% ({confirm, ...}): T is confirmed where its count is still whole and has
%% had no withdrawal since. Why that is safe, when the reports of the sites
%% are made at different moments: a withdrawal of T after the confirmations
%% is a rollback below T, caused by an event or antievent about a time
%% before T. Its sender sent it from below T, and waits for its
%% acknowledgement before it commits T again; the acknowledgement comes
%% after the withdrawal, so after every confirmation, and every
%% confirmation comes after every report. So the sender's T was not
%% committed at some moment between its site's report and its site's
%% confirmation, which its site would have seen as a withdrawal - unless
%% the sender sent it after its own confirmation, having itself been rolled
%% back below T after it: an earlier such withdrawal. The earliest one has
%% no cause, so there is none. (On one node, rw_gvt reads the count once,
%% which is the same argument with one site.)
%%
%% The records the run needs of the sync points confirmed (frame times it
%% shows, checkpoints, regroup points) go with the answer; a sync point
%% confirmed here but not everywhere is asked again, and its records sent
%% again. Then {gvt, G, Moves} comes: the regroup moves for entities here
%% are passed on first (as rw_gvt sends them before it publishes GVT on one
%% node), then GVT is published to the entities and the buckets of this
%% node, whoever asked to be woken is, and the commits up to G are
%% forgotten.
-module(rw_gvt_site).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/3]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-record(s, {
    sim :: #sim{},
    run_gvt :: pid(),
    buckets :: [pid()],                      % this node's
    waiting = rw_wakeups:new() :: rw_wakeups:wakeups(),
    buckets_told = -1 :: integer()           % the GVT this node's buckets last heard of
}).

-spec start_link(#sim{}, pid(), [pid()]) -> {ok, pid()}.
start_link(Sim, RunGvt, Buckets) -> gen_server:start_link(?MODULE, {Sim, RunGvt, Buckets}, []).

-spec init({#sim{}, pid(), [pid()]}) -> {ok, #s{}}.
init({Sim, RunGvt, Buckets}) ->
    {ok, #s{sim = Sim, run_gvt = RunGvt, buckets = Buckets}}.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, {error, unknown_call}, #s{}}.
handle_call(_Req, _From, S) -> {reply, {error, unknown_call}, S}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({complete, T}, #s{sim = Sim} = S) ->
    Whole = [{Ti, W} || Ti <- lists:usort(more_complete([T])), {C, W} <- [rw_commits:count(Sim, Ti)],
                        C =:= Sim#sim.n],
    _ = [S#s.run_gvt ! {site_complete, self(), Whole} || Whole =/= []],
    {noreply, S};
handle_info({confirm, Ref, Checks, Need}, #s{sim = Sim} = S) ->
    {Confirmed, Rest} = confirm(Checks, Sim),
    Records = lists:append([rw_commits:records_at(T, Sim#sim.records) || T <- Confirmed, lists:member(T, Need)]),
    S#s.run_gvt ! {confirmed, Ref, self(), Confirmed, Rest, Records, met(Sim)},
    {noreply, S};
handle_info({gvt, G, Moves}, #s{sim = Sim, waiting = W} = S) ->
    _ = [Pid ! Msg || {Pid, Msg} <- Moves],
    ok = atomics:put(Sim#sim.gvt_now, 1, G),
    Told = rw_bucket:gvt(S#s.buckets, G, S#s.buckets_told, (Sim#sim.scene)#scene.substep),
    S1 = S#s{waiting = rw_wakeups:wake(G, W), buckets_told = Told},
    ok = rw_commits:forget_through(Sim, G),
    {noreply, S1};
handle_info({wake_at, Pid, At}, #s{sim = Sim} = S) ->
    case atomics:get(Sim#sim.gvt_now, 1) of
        G when At =< G -> Pid ! {gvt, G}, {noreply, S};
        _ -> {noreply, S#s{waiting = rw_wakeups:add(At, Pid, S#s.waiting)}}
    end;
handle_info({regroup_ack, _At, _Pid} = Ack, S) ->
    S#s.run_gvt ! Ack,
    {noreply, S};
handle_info(Msg, S) ->
    logger:warning("rw_gvt_site: unexpected message ~p", [Msg]),
    {noreply, S}.

more_complete(Ts) ->
    receive
        {complete, T} -> more_complete([T | Ts])
    after 0 -> Ts
    end.

%% The sync points Checks ([{T, Withdrawals}], ascending) still whole
%% with no withdrawal since, up to the first that is not; and what is
%% known of the others now: {T, Withdrawals} if whole, {T, none} if not.
confirm(Checks, Sim) -> confirm(Checks, Sim, []).

confirm([], _Sim, Acc) -> {lists:reverse(Acc), []};
confirm([{T, W} | Rest] = Checks, #sim{n = N} = Sim, Acc) ->
    case rw_commits:count(Sim, T) of
        {N, W} -> confirm(Rest, Sim, [T | Acc]);
        _ -> {lists:reverse(Acc), [now_known(Ti, Sim) || {Ti, _} <- Checks]}
    end.

now_known(T, #sim{n = N} = Sim) ->
    case rw_commits:count(Sim, T) of
        {N, W} -> {T, W};
        _ -> {T, none}
    end.

%% The pairs that met often since the last answer (for the contact groups,
%% which only ever join bodies of one node).
met(#sim{met = Met}) ->
    lists:append([ets:take(Met, Pair) || Pair <- ets:select(Met, [{{'$1', '_'}, [], ['$1']}])]).

