%% A bucket of the temporal volumetric hash table (TVHT). A fixed pool of
%% buckets shares the cells of Z^3 (rw_hash:bucket/2). A bucket keeps the
%% states written at each (LVT, cell), runs the narrowphase when a body
%% writes, remembers the contacts it reported, returns them when one of the
%% two states is deleted, and locks cells for one writer at a time.
%%
%% Locking (Lemma 1): a body asks the buckets it needs in increasing bucket
%% index, and a bucket grants a request for a set of its cells only when all
%% of them are free. Resources are thus acquired in one global order
%% (bucket index), so there is no circular wait. Lock and probe (or lock and
%% delete) are one call: the answer is computed while the lock is held.
-module(rw_bucket).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/2, lock_probe/4, commit_unlock/4, lock_delete/4, unlock/2, gvt/2]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).
-export_type([entry/0, write/0, hit/0]).

%% What a body writes at one LVT: who it is and its state (and, with CCD,
%% its free displacement over the substep).
-type entry() :: {Idx :: non_neg_integer(), pid(), #sphere{}, #st{}, Disp :: rw_vec:vec() | undefined}.
-type write() :: {T :: non_neg_integer(), entry(), [rw_hash:cell()]}.
%% A contact found by the narrowphase, in canonical order (lower idx first).
-type hit() :: {entry(), #contact{}}.
-type cid() :: {non_neg_integer(), non_neg_integer(), non_neg_integer(), reference()}.

-record(state, {
    model :: #model{},
    locks = #{} :: #{rw_hash:cell() => pid()},
    waiting = [] :: [{gen_server:from(), pid(), [rw_hash:cell()], term()}],
    states = #{} :: #{non_neg_integer() => #{rw_hash:cell() => [entry()]}},
    %% contacts reported from this bucket: by {T, Idx} of either body
    by_body = #{} :: #{{non_neg_integer(), non_neg_integer()} => [cid()]},
    contacts = #{} :: #{cid() => {Detector :: pid(), Other :: pid()}},
    probes = #{} :: #{pid() => {non_neg_integer(), [hit()]} | none}
}).

-spec start_link(#model{}, non_neg_integer()) -> {ok, pid()}.
start_link(Model, _Index) -> gen_server:start_link(?MODULE, Model, []).

%% Lock Cells for the caller, then find the earliest write with contacts:
%% returns {T, Hits} or none. The caller must follow with commit_unlock/4.
-spec lock_probe(pid(), pid(), [rw_hash:cell()], [write()]) -> {non_neg_integer(), [hit()]} | none.
lock_probe(Bucket, Owner, Cells, Writes) ->
    gen_server:call(Bucket, {lock, Owner, Cells, {probe, Writes}}, infinity).

%% Store the writes up to and including UpTo, record the contacts at UpTo
%% under the ids the writer gave them, and unlock.
-spec commit_unlock(pid(), pid(), non_neg_integer(), #{non_neg_integer() => cid()}) -> ok.
commit_unlock(Bucket, Owner, UpTo, Ids) ->
    gen_server:cast(Bucket, {commit_unlock, Owner, UpTo, Ids}).

%% Lock Cells, delete the caller's states [{T, Idx, CellsAtT}] and return
%% the contacts that those states had: [{Cid, Detector, Other}].
-spec lock_delete(pid(), pid(), [rw_hash:cell()], [{non_neg_integer(), non_neg_integer(), [rw_hash:cell()]}]) ->
          [{cid(), pid(), pid()}].
lock_delete(Bucket, Owner, Cells, Deletes) ->
    gen_server:call(Bucket, {lock, Owner, Cells, {delete, Deletes}}, infinity).

-spec unlock(pid(), pid()) -> ok.
unlock(Bucket, Owner) -> gen_server:cast(Bucket, {unlock, Owner}).

%% Forget everything older than GVT.
-spec gvt(pid(), non_neg_integer()) -> ok.
gvt(Bucket, Gvt) -> gen_server:cast(Bucket, {gvt, Gvt}).

%%% gen_server

-spec init(#model{}) -> {ok, #state{}}.
init(Model) -> {ok, #state{model = Model}}.

-spec handle_call(term(), gen_server:from(), #state{}) -> {reply, term(), #state{}} | {noreply, #state{}}.
handle_call({lock, Owner, Cells, Op}, From, S) ->
    case free(Cells, Owner, S#state.locks) of
        true -> {Reply, S1} = locked_op(Owner, Op, S#state{locks = take(Cells, Owner, S#state.locks)}),
                {reply, Reply, S1};
        false -> {noreply, S#state{waiting = S#state.waiting ++ [{From, Owner, Cells, Op}]}}
    end.

-spec handle_cast(term(), #state{}) -> {noreply, #state{}}.
handle_cast({commit_unlock, Owner, UpTo, Ids}, S) ->
    {noreply, release(Owner, commit(Owner, UpTo, Ids, S))};
handle_cast({unlock, Owner}, S) ->
    {noreply, release(Owner, S)};
handle_cast({gvt, Gvt}, #state{states = St, by_body = By, contacts = C} = S) ->
    Old = [K || {T, _} = K <- maps:keys(By), T < Gvt],
    Cids = lists:append([maps:get(K, By) || K <- Old]),
    {noreply, S#state{states = maps:filter(fun(T, _) -> T >= Gvt end, St),
                      by_body = maps:without(Old, By),
                      contacts = maps:without(Cids, C)}}.

-spec handle_info(term(), #state{}) -> {noreply, #state{}}.
handle_info(Msg, S) ->
    logger:warning("rw_bucket ~p: unexpected message ~p", [self(), Msg]),
    {noreply, S}.

%%% Locks

free(Cells, Owner, Locks) ->
    lists:all(fun(C) -> case Locks of
                            #{C := Other} -> Other =:= Owner;
                            _ -> true
                        end end, Cells).

take(Cells, Owner, Locks) -> lists:foldl(fun(C, L) -> L#{C => Owner} end, Locks, Cells).

%% Drop Owner's locks and grant waiting requests that now fit, in order.
release(Owner, #state{locks = Locks} = S) ->
    grant(S#state{locks = maps:filter(fun(_, O) -> O =/= Owner end, Locks)}).

grant(#state{waiting = Waiting} = S) -> grant(Waiting, [], S).

grant([], Kept, S) -> S#state{waiting = lists:reverse(Kept)};
grant([{From, Owner, Cells, Op} = W | Rest], Kept, S) ->
    case free(Cells, Owner, S#state.locks) of
        true ->
            {Reply, S1} = locked_op(Owner, Op, S#state{locks = take(Cells, Owner, S#state.locks)}),
            gen_server:reply(From, Reply),
            grant(Rest, Kept, S1);
        false ->
            grant(Rest, [W | Kept], S)
    end.

%%% Operations under lock

locked_op(Owner, {probe, Writes}, S) ->
    Result = probe(Writes, S),
    {Result, S#state{probes = (S#state.probes)#{Owner => {Writes, Result}}}};
locked_op(_Owner, {delete, Deletes}, S) ->
    delete(Deletes, S).

%% The first write (in LVT order) that touches another body's state.
probe([], _S) -> none;
probe([{T, Entry, Cells} | Rest], #state{states = States, model = M} = S) ->
    AtT = maps:get(T, States, #{}),
    Hits = lists:usort(fun({{IA, _, _, _, _}, _}, {{IB, _, _, _, _}, _}) -> IA =< IB end,
                       [{Other, C} || Cell <- Cells, Other <- maps:get(Cell, AtT, []),
                                      C <- contact(M, Entry, Other)]),
    case Hits of
        [] -> probe(Rest, S);
        _ -> {T, Hits}
    end.

contact(_M, {Idx, _, _, _, _}, {Idx, _, _, _, _}) -> [];
contact(M, {IA, _, _, _, _} = A, {IB, _, _, _, _} = B) when IA < IB -> narrow(M, A, B);
contact(M, A, B) -> narrow(M, B, A).

%% Narrowphase in canonical order: A has the lower index.
narrow(#model{ccd = false}, {_, _, #sphere{radius = RA}, #st{p = PA}, _}, {_, _, #sphere{radius = RB}, #st{p = PB}, _}) ->
    case rw_narrow:sphere_sphere(PA, RA, PB, RB) of
        none -> [];
        C -> [C]
    end;
narrow(#model{ccd = true}, {_, _, #sphere{radius = RA}, #st{p = PA}, DA},
       {_, _, #sphere{radius = RB}, #st{p = PB}, DB}) ->
    case rw_narrow:swept_sphere_sphere(PA, DA, RA, PB, DB, RB) of
        none -> [];
        C -> [C]
    end.

commit(Owner, UpTo, Ids, #state{probes = Probes} = S) ->
    {{Writes, Result}, Probes1} = maps:take(Owner, Probes),
    S1 = lists:foldl(fun({T, Entry, Cells}, Acc) when T =< UpTo -> store(T, Entry, Cells, Acc);
                        (_, Acc) -> Acc
                     end, S#state{probes = Probes1}, Writes),
    case Result of
        {UpTo, Hits} ->
            {value, {_, {Idx, _, _, _, _}, _}} = lists:keysearch(UpTo, 1, Writes),
            lists:foldl(fun({{OIdx, OPid, _, _, _}, _}, Acc) ->
                                record(maps:get(OIdx, Ids), UpTo, Idx, Owner, OIdx, OPid, Acc)
                        end, S1, Hits);
        _ ->
            S1
    end.

store(T, Entry, Cells, #state{states = States} = S) ->
    AtT = maps:get(T, States, #{}),
    AtT1 = lists:foldl(fun(C, A) -> A#{C => [Entry | maps:get(C, A, [])]} end, AtT, Cells),
    S#state{states = States#{T => AtT1}}.

record(Cid, T, Idx, Detector, OIdx, Other, #state{by_body = By, contacts = C} = S) ->
    By1 = maps:update_with({T, OIdx}, fun(L) -> [Cid | L] end, [Cid],
                           maps:update_with({T, Idx}, fun(L) -> [Cid | L] end, [Cid], By)),
    S#state{by_body = By1, contacts = C#{Cid => {Detector, Other}}}.

delete(Deletes, S0) ->
    lists:foldl(
      fun({T, Idx, Cells}, {Acc, #state{states = States, by_body = By, contacts = C} = S}) ->
              AtT = maps:get(T, States, #{}),
              AtT1 = lists:foldl(fun(Cell, A) ->
                                         case [E || E <- maps:get(Cell, A, []), element(1, E) =/= Idx] of
                                             [] -> maps:remove(Cell, A);
                                             Es -> A#{Cell => Es}
                                         end
                                 end, AtT, Cells),
              States1 = case map_size(AtT1) of 0 -> maps:remove(T, States); _ -> States#{T => AtT1} end,
              {Cids, By1} = case maps:take({T, Idx}, By) of
                                {L, B} -> {L, B};
                                error -> {[], By}
                            end,
              Gone = [{Cid, D, O} || Cid <- Cids, {D, O} <- [maps:get(Cid, C, undefined)], D =/= undefined],
              {Gone ++ Acc, S#state{states = States1, by_body = By1,
                                    contacts = maps:without(Cids, C)}}
      end, {[], S0}, Deletes).
