%% Forgets the committed records that the GVT process is done with: those
%% of a frame that has left the ring, and of a sync point that is no frame
%% once GVT has passed it. Deleting a frame's records (one per body) in
%% the GVT process, which every body waits for, took a sixth of its time
%% in Cylinders 500; here it runs beside it. No one reads those records
%% again, so forgetting them a little later changes nothing. A child of
%% the simulation's tree (rw_sim_sup), so that a simulation stopped after
%% a fault has stopped forgetting before its successor commits those
%% times again.
-module(rw_sweeper).
-behaviour(gen_server).
-export([start_link/1, forget/2, sync/1]).
-export([init/1, handle_call/3, handle_cast/2]).

-spec start_link(ets:tid()) -> {ok, pid()}.
start_link(Records) -> gen_server:start_link(?MODULE, Records, []).

%% Forget the records of sync point T.
-spec forget(pid(), non_neg_integer()) -> ok.
forget(Sweeper, T) -> gen_server:cast(Sweeper, {forget, T}).

%% Once every record the caller asked it to forget is gone: at the end of
%% a run the records table holds only the ring's frames.
-spec sync(pid()) -> ok.
sync(Sweeper) -> gen_server:call(Sweeper, sync, infinity).

-spec init(ets:tid()) -> {ok, ets:tid()}.
init(Records) -> {ok, Records}.

-spec handle_call(term(), gen_server:from(), ets:tid()) -> {reply, ok | {error, unknown_call}, ets:tid()}.
handle_call(sync, _From, Records) ->
    {reply, ok, Records};
handle_call(Req, _From, Records) ->
    logger:warning("rw_sweeper: unexpected call ~p", [Req]),
    {reply, {error, unknown_call}, Records}.

-spec handle_cast({forget, non_neg_integer()}, ets:tid()) -> {noreply, ets:tid()}.
handle_cast({forget, T}, Records) ->
    ok = rw_commits:delete_at(T, Records),
    {noreply, Records}.
