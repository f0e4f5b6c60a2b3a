%% A bucket of the temporal volumetric hash table (TVHT): the process that
%% holds one share of the cells of Z^3 (rw_hash:bucket/2 says which) and
%% their contents (rw_cells; their segments in C where the library is
%% loaded), and locks cells for one writer at a
%% time. An entity (rw_body: one body, or a group of bodies in persistent
%% contact) writes the states of one step at once; rw_tvht is the client
%% side.
%%
%% Locking (Lemma 1): an entity asks the buckets it needs in increasing
%% bucket index, and a bucket grants a request for a set of its cells only
%% when all of them are free. Resources are thus acquired in one global
%% order (bucket index), so there is no circular wait. Lock and probe (or
%% lock and delete) are one call: the answer is computed while the lock is
%% held.
-module(rw_bucket).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/6, lock_probe/4, commit_unlock/4, probe_commit/5, lock_delete/5, unlock/2, gvt/4]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-record(state, {
    cells :: rw_cells:cells(),
    locks = #{} :: #{rw_hash:cell() => pid()},
    held = #{} :: #{pid() => [rw_hash:cell()]},   % the same locks by owner
    %% requests waiting for locks, by arrival, and by the cells they want:
    %% when locks are dropped only the requests for those cells are looked
    %% at again (every body of a large scene writes at once at its start)
    waiting = #{} :: #{pos_integer() => {{pid(), reference()}, pid(), [rw_hash:cell()], term()}},
    by_cell = #{} :: #{rw_hash:cell() => [pos_integer()]},
    arrivals = 0 :: non_neg_integer(),
    probes = #{} :: #{pid() => {rw_cells:write(), [rw_cells:span()], {non_neg_integer(), [rw_cells:hit()]} | none}},
    %% when profiling: the simulation's counters
    profile :: rw_stats:counters() | undefined
}).

%% Store: where the segments are kept (rw_cells:new/3: native only where
%% the C library is loaded); Profile: the simulation's counters when its
%% work is profiled; Trace: where its work is recorded (rw_trace) when the
%% simulation is traced; its heap never shrinks below MinHeap words. A
%% bucket runs at high priority, as does a caller while it waits for its
%% answer (locked_call/2).
-spec start_link(#model{}, pos_integer(), erlang | native, rw_stats:counters() | undefined, ets:tid() | undefined,
                 pos_integer()) -> {ok, pid()}.
start_link(Model, Dt, Store, Profile, Trace, MinHeap) ->
    gen_server:start_link(?MODULE, {Model, Dt, Store, Profile, Trace},
                          [{spawn_opt, [{min_heap_size, MinHeap}, {priority, high}]}]).

%% Lock Cells for the caller, then find the earliest LVT at which one of
%% the written members touches another body: {T, Hits} or none. The caller
%% must follow with commit_unlock/4.
-spec lock_probe(pid(), [rw_hash:cell()], rw_cells:write(), [rw_cells:span()]) ->
          {non_neg_integer(), [rw_cells:hit()]} | none.
lock_probe(Bucket, Cells, {Owner, _, _, _} = Write, Spans) ->
    locked_call(Bucket, {lock, Owner, Cells, {probe, Write, Spans}}).

%% Store the probed states up to and including UpTo, record the contacts
%% at UpTo under the ids the writer gave them (by {member, partner} idx),
%% and unlock.
-spec commit_unlock(pid(), pid(), non_neg_integer(), rw_cells:ids()) -> ok.
commit_unlock(Bucket, Owner, UpTo, Ids) ->
    cast(Bucket, {commit_unlock, Owner, UpTo, Ids}).

%% lock_probe/4 and commit_unlock/4 in one call, for a write whose cells
%% are all in this bucket: the states are stored up to the first LVT with
%% contacts (or Last), and the contacts there get ids. No lock outlives
%% the call, so no other writer waits on this one's messages.
-spec probe_commit(pid(), [rw_hash:cell()], rw_cells:write(), [rw_cells:span()], non_neg_integer()) ->
          {UpTo :: non_neg_integer(), [rw_cells:hit()], rw_cells:ids()}.
probe_commit(Bucket, Cells, {Owner, _, _, _} = Write, Spans, Last) ->
    locked_call(Bucket, {lock, Owner, Cells, {probe_commit, Write, Spans, Last}}).

%% Lock Cells, delete the caller's states after R in them (of its members
%% Idxs), and return the contacts those states had: [{Cid, Detector,
%% Other}]. Unlock with unlock/2. (A rollback never reaches a regroup
%% point, so every state after R was written by the caller.)
-spec lock_delete(pid(), pid(), [rw_hash:cell()], [non_neg_integer()], non_neg_integer()) ->
          [{rw_cells:cid(), pid(), pid()}].
lock_delete(Bucket, Owner, Cells, Idxs, R) ->
    locked_call(Bucket, {lock, Owner, Cells, {delete, Idxs, R, Cells}}).

%% A request and its answer, as gen_server:call/3 without the monitor that
%% call sets up and takes down each time (a tenth of the cost of a write to
%% the TVHT): a bucket that died has taken its simulation down with it, and
%% the caller with it (rw_sim_sup). The answer is matched by a fresh
%% reference, which the runtime finds without scanning older messages.
%%
%% The caller waits at high priority, and the bucket runs at high priority:
%% the request is served, and the caller resumes, as soon as a scheduler is
%% free, not after every runnable body has had its turn. At normal priority
%% a write of 20,000 spheres waited for thousands of other steps, and the
%% bucket and the caller then found their data gone from the caches
%% (doc/performance.md).
locked_call(Bucket, Req) ->
    Old = process_flag(priority, high),
    Reply = answer(Bucket, Req),
    _ = process_flag(priority, Old),
    Reply.

answer(Bucket, Req) ->
    Ref = make_ref(),
    Call = {'$rw_call', {self(), Ref}, Req},
    case rw_trace:table() of
        undefined ->
            Bucket ! Call,
            receive {Ref, Reply} -> Reply end;
        _ ->
            %% traced: the caller's task ends with the call, and another
            %% begins with the answer
            ok = rw_trace:send(Bucket, Call),
            ok = rw_trace:end_task(),
            receive
                {Ref, Reply} = Answer ->
                    ok = rw_trace:begin_task(body, Answer),
                    Reply
            end
    end.

reply({Pid, Ref}, Reply) -> rw_trace:send(Pid, {Ref, Reply}).

cast(Bucket, Msg) ->
    ok = rw_trace:sent(Bucket, Msg),
    gen_server:cast(Bucket, Msg).

-spec unlock(pid(), pid()) -> ok.
unlock(Bucket, Owner) -> cast(Bucket, {unlock, Owner}).

%% Nothing before GVT can change any more: the buckets forget it. A
%% bucket sweeps its cells only once GVT has moved on by
%% rw_cells:sweep_every/1 since its last sweep, so they are told only then,
%% not at every sync point. Told is the GVT they were told last (-1:
%% none); the answer is the new one.
-spec gvt([pid()], non_neg_integer(), integer(), pos_integer()) -> integer().
gvt(Buckets, Gvt, Told, Dt) ->
    case Told >= 0 andalso Gvt < Told + rw_cells:sweep_every(Dt) of
        true ->
            Told;
        false ->
            _ = [cast(B, {gvt, Gvt}) || B <- Buckets],
            Gvt
    end.

%%% gen_server

-spec init({#model{}, pos_integer(), erlang | native, rw_stats:counters() | undefined, ets:tid() | undefined}) ->
          {ok, #state{}}.
init({Model, Dt, Store, Profile, Trace}) ->
    ok = rw_trace:init(Trace),
    %% (its Erlang store scans in Erlang too: one setting per run)
    ok = rw_native:use(Store =:= native),
    {ok, #state{cells = rw_cells:new(Model, Dt, Store), profile = Profile}}.

-spec handle_call(term(), gen_server:from(), #state{}) -> {reply, term(), #state{}}.
handle_call(Req, _From, S) ->
    logger:warning("rw_bucket ~p: unexpected call ~p", [self(), Req]),
    {reply, {error, unexpected}, S}.

-spec handle_cast(term(), #state{}) -> {noreply, #state{}}.
handle_cast(Msg, S) -> {noreply, instrumented(Msg, S)}.

handle({commit_unlock, Owner, UpTo, Ids}, #state{probes = Probes, cells = Cells} = S) ->
    {{Write, Spans, Result}, Probes1} = maps:take(Owner, Probes),
    release(Owner, S#state{probes = Probes1, cells = rw_cells:store(Owner, Write, Spans, Result, UpTo, Ids, Cells)});
handle({unlock, Owner}, S) ->
    release(Owner, S);
handle({gvt, Gvt}, #state{cells = Cells} = S) ->
    S#state{cells = rw_cells:gc(Gvt, Cells)}.

-spec handle_info(term(), #state{}) -> {noreply, #state{}}.
handle_info({'$rw_call', _, _} = Msg, S) -> {noreply, instrumented(Msg, S)};
handle_info(Msg, S) ->
    logger:warning("rw_bucket ~p: unexpected message ~p", [self(), Msg]),
    {noreply, S}.

%% Handle Msg (a call or a cast): counted when the simulation is profiled,
%% a task when it is traced. Otherwise it is handled without a fun: on this
%% runtime every fun made is also linked into the process's list of
%% off-heap terms, which each garbage collection walks.
instrumented(Msg, #state{profile = undefined} = S) ->
    case rw_trace:table() of
        undefined -> dispatch(Msg, S);
        _ -> rw_trace:task(bucket, Msg, fun() -> dispatch(Msg, S) end)
    end;
instrumented(Msg, #state{profile = Stats} = S) ->
    rw_trace:task(bucket, Msg, fun() -> rw_stats:timed(Stats, tvht_reductions, fun() -> dispatch(Msg, S) end) end).

dispatch({'$rw_call', From, Req}, S) -> call(Req, From, S);
dispatch(Msg, S) -> handle(Msg, S).

call({lock, Owner, Cells, Op}, From, S) ->
    case free(Cells, Owner, S#state.locks) of
        true ->
            {Reply, S1} = locked_op(Owner, Op, take(Cells, Owner, S)),
            reply(From, Reply),
            S1;
        false ->
            #state{waiting = W, by_cell = ByCell, arrivals = N} = S,
            Seq = N + 1,
            S#state{waiting = W#{Seq => {From, Owner, Cells, Op}}, arrivals = Seq,
                    by_cell = lists:foldl(fun(C, B) -> maps:update_with(C, fun(L) -> [Seq | L] end, [Seq], B) end,
                                          ByCell, lists:usort(Cells))}
    end.

%%% Locks

%% (free/3 and lock/3 recurse where lists:all/2 and lists:foldl/3 would
%% take a fun made at each call: see instrumented/2)
free([], _Owner, _Locks) -> true;
free([C | Cells], Owner, Locks) ->
    case Locks of
        #{C := Owner} -> free(Cells, Owner, Locks);
        #{C := _} -> false;
        _ -> free(Cells, Owner, Locks)
    end.

take(Cells, Owner, #state{locks = Locks, held = Held} = S) ->
    S#state{locks = lock(Cells, Owner, Locks), held = Held#{Owner => Cells ++ maps:get(Owner, Held, [])}}.

lock([], _Owner, Locks) -> Locks;
lock([C | Cells], Owner, Locks) -> lock(Cells, Owner, Locks#{C => Owner}).

%% Drop Owner's locks and grant the waiting requests for those cells that
%% now fit, in order of arrival (a request waits only while one of its
%% cells is locked by another, so none other can fit now).
release(Owner, S) ->
    {Cells, S1} = drop_locks(Owner, S),
    grant(Cells, S1).

%% Owner's locks dropped, and the cells they were on.
drop_locks(Owner, #state{locks = Locks, held = Held} = S) ->
    case maps:take(Owner, Held) of
        {Cells, Held1} -> {Cells, S#state{locks = maps:without(Cells, Locks), held = Held1}};
        error -> {[], S}
    end.

grant(_Released, #state{waiting = W} = S) when map_size(W) =:= 0 -> S;
grant(Released, #state{by_cell = ByCell} = S) ->
    lists:foldl(fun grant_one/2, S, lists:usort(lists:append([maps:get(C, ByCell, []) || C <- Released]))).

grant_one(Seq, #state{waiting = Waiting, by_cell = ByCell} = S) ->
    case Waiting of
        #{Seq := {From, Owner, Cells, Op}} ->
            case free(Cells, Owner, S#state.locks) of
                true ->
                    Gone = lists:foldl(fun(C, B) ->
                                               case lists:delete(Seq, maps:get(C, B)) of
                                                   [] -> maps:remove(C, B);
                                                   L -> B#{C := L}
                                               end
                                       end, ByCell, lists:usort(Cells)),
                    {Reply, S1} = locked_op(Owner, Op, take(Cells, Owner,
                                                            S#state{waiting = maps:remove(Seq, Waiting), by_cell = Gone})),
                    reply(From, Reply),
                    S1;
                false ->
                    S
            end;
        _ ->
            S
    end.

%%% Operations under lock

locked_op(Owner, {probe, Write, Spans}, #state{cells = Cells} = S) ->
    Result = rw_cells:probe(Write, Spans, Cells),
    {Result, S#state{probes = (S#state.probes)#{Owner => {Write, Spans, Result}}}};
locked_op(Owner, {probe_commit, Write, Spans, Last}, #state{cells = Cells} = S) ->
    Result = rw_cells:probe(Write, Spans, Cells),
    {UpTo, Hits} = case Result of
                       none -> {Last, []};
                       Found -> Found
                   end,
    Pairs = [{Idx, OIdx} || {Idx, {OIdx, _, _, _, _}, _} <- Hits],
    Ids = rw_cells:contact_ids(UpTo, Pairs, [make_ref() || _ <- Pairs]),
    S1 = S#state{cells = rw_cells:store(Owner, Write, Spans, Result, UpTo, Ids, Cells)},
    %% The cells were free when this call took them, so freeing them again
    %% changes nothing for the requests still waiting (and granting here
    %% would re-enter grant/3, which may be running this very call).
    {_, S2} = drop_locks(Owner, S1),
    {{UpTo, Hits, Ids}, S2};
locked_op(Owner, {delete, Idxs, R, Owned}, #state{cells = Cells} = S) ->
    {Lost, Cells1} = rw_cells:delete(Owner, Idxs, R, Owned, Cells),
    {Lost, S#state{cells = Cells1}}.
