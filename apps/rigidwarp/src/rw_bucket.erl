%% A bucket of the temporal volumetric hash table (TVHT). A fixed pool of
%% buckets shares the cells of Z^3 (rw_hash:bucket/2). An entity (rw_body:
%% one body, or a group of bodies in persistent contact) writes the states
%% of one step at once: for each cell its members' AABBs touch, the range of
%% substeps [Ta, Tb] during which each member does. A bucket keeps, per
%% cell and writer, one segment per write (newest first), runs the
%% narrowphase on a write against the other writers' states at the same
%% LVT in the same cell, remembers the contacts it reported, returns them
%% when one of the two states is deleted, and locks cells for one writer at
%% a time. Contacts among the members of one write are not its business:
%% the writer finds those itself (rw_island).
%%
%% Keeping a group's members together per cell lets a probe skip its own
%% group with one comparison, and a foreign group whose write lies apart
%% from its own with one more (Cylinders' rows of piles share cells but
%% never touch); only then are member pairs compared, by time and box.
%%
%% Locking (Lemma 1): a body asks the buckets it needs in increasing bucket
%% index, and a bucket grants a request for a set of its cells only when all
%% of them are free. Resources are thus acquired in one global order
%% (bucket index), so there is no circular wait. Lock and probe (or lock and
%% delete) are one call: the answer is computed while the lock is held.
-module(rw_bucket).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/3, lock_probe/4, commit_unlock/4, probe_commit/5, lock_delete/5, unlock/2, gvt/2, profile/2,
         contact_ids/2]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).
-export_type([entry/0, payload/0, write/0, span/0, bounds/0, hit/0, cid/0]).

%% One step's states of one member: T0 is the LVT of the first state,
%% States (and, with CCD, the free displacements) hold one per substep,
%% Bounds is a box that holds the sphere (swept, with CCD) at all of them.
-type payload() :: {Idx :: non_neg_integer(), pid(), #sphere{}, T0 :: non_neg_integer(),
                    States :: rw_states:packed(), Bounds :: bounds()}.
-type bounds() :: rw_shape:box6().
%% One entity's step: the writer, its first substep, its members' payloads
%% and a box that holds them all.
-type write() :: {Writer :: pid(), T0 :: non_neg_integer(), #{non_neg_integer() => payload()}, bounds()}.
%% A cell touched by the write from Ta to Tb, and by each member from its
%% own Ta to Tb.
-type span() :: {rw_hash:cell(), Ta :: non_neg_integer(), Tb :: non_neg_integer(), [member_span()]}.
-type member_span() :: {Idx :: non_neg_integer(), Ta :: non_neg_integer(), Tb :: non_neg_integer()}.
%% One body's state at one LVT, as the narrowphase sees it.
-type entry() :: {Idx :: non_neg_integer(), pid(), #sphere{}, #st{}, Disp :: rw_vec:vec() | undefined}.
%% A contact found by the narrowphase between the writer's member MyIdx and
%% another body, in canonical order (lower idx first).
-type hit() :: {MyIdx :: non_neg_integer(), entry(), #contact{}}.
-type cid() :: {non_neg_integer(), non_neg_integer(), non_neg_integer(), reference()}.
%% A write's presence in one cell.
-type seg() :: {Ta :: non_neg_integer(), Tb :: non_neg_integer(), write(), [member_span()]}.

-record(state, {
    model :: #model{},
    dt :: pos_integer(),                     % substep, ticks
    locks = #{} :: #{rw_hash:cell() => pid()},
    held = #{} :: #{pid() => [rw_hash:cell()]},   % the same locks by owner
    waiting = [] :: [{gen_server:from(), pid(), [rw_hash:cell()], term()}],
    %% per cell, per writer, its segments newest first: an entity writes
    %% forward in time and a rollback cuts the newest ones, so each list is
    %% sorted and a probe near the present reads only its head
    cells = #{} :: #{rw_hash:cell() => #{pid() => [seg()]}},
    %% contacts reported from this bucket, by body: [{T, Cid}]
    by_body = #{} :: #{non_neg_integer() => [{non_neg_integer(), cid()}]},
    contacts = #{} :: #{cid() => {Detector :: pid(), Other :: pid()}},
    probes = #{} :: #{pid() => {write(), [span()], {non_neg_integer(), [hit()]} | none}},
    gc_at = 0 :: non_neg_integer(),
    %% when profiling: the simulation's counters (tvht_reductions is counter 7)
    profile = undefined :: counters:counters_ref() | undefined
}).

-define(TVHT_REDS, 7).

-spec start_link(#model{}, pos_integer(), non_neg_integer()) -> {ok, pid()}.
start_link(Model, Dt, _Index) -> gen_server:start_link(?MODULE, {Model, Dt}, []).

%% Lock Cells for the caller, then find the earliest LVT at which one of
%% the written members touches another body: {T, Hits} or none. The caller
%% must follow with commit_unlock/4.
-spec lock_probe(pid(), [rw_hash:cell()], write(), [span()]) -> {non_neg_integer(), [hit()]} | none.
lock_probe(Bucket, Cells, {Owner, _, _, _} = Write, Spans) ->
    locked_call(Bucket, {lock, Owner, Cells, {probe, Write, Spans}}).

%% Store the probed states up to and including UpTo, record the contacts
%% at UpTo under the ids the writer gave them (by {member, partner} idx),
%% and unlock.
-spec commit_unlock(pid(), pid(), non_neg_integer(), ids()) -> ok.
commit_unlock(Bucket, Owner, UpTo, Ids) ->
    gen_server:cast(Bucket, {commit_unlock, Owner, UpTo, Ids}).

%% lock_probe/4 and commit_unlock/4 in one call, for a write whose cells
%% are all in this bucket: the states are stored up to the first LVT with
%% contacts (or Last), and the contacts there get ids. No lock outlives
%% the call, so no other writer waits on this one's messages.
-spec probe_commit(pid(), [rw_hash:cell()], write(), [span()], non_neg_integer()) ->
          {UpTo :: non_neg_integer(), [hit()], ids()}.
probe_commit(Bucket, Cells, {Owner, _, _, _} = Write, Spans, Last) ->
    locked_call(Bucket, {lock, Owner, Cells, {probe_commit, Write, Spans, Last}}).

%% The ids of the contacts at T between the writer's members and other
%% bodies, by {member idx, partner idx}: {T, lower idx, higher idx, unique}.
-type ids() :: #{{non_neg_integer(), non_neg_integer()} => cid()}.
-spec contact_ids(non_neg_integer(), [{non_neg_integer(), non_neg_integer()}]) -> ids().
contact_ids(T, Pairs) ->
    maps:from_list([{{Idx, OIdx}, {T, min(Idx, OIdx), max(Idx, OIdx), make_ref()}} || {Idx, OIdx} <- Pairs]).

%% Lock Cells, delete the caller's states after R in them (of its members
%% Idxs), and return the contacts those states had: [{Cid, Detector,
%% Other}]. Unlock with unlock/2. (A rollback never reaches a regroup
%% point, so every state after R was written by the caller.)
-spec lock_delete(pid(), pid(), [rw_hash:cell()], [non_neg_integer()], non_neg_integer()) ->
          [{cid(), pid(), pid()}].
lock_delete(Bucket, Owner, Cells, Idxs, R) ->
    locked_call(Bucket, {lock, Owner, Cells, {delete, Idxs, R, Cells}}).

%% A request and its answer, as gen_server:call/3 without the monitor that
%% call sets up and takes down each time (a tenth of the cost of a write to
%% the TVHT): a bucket that died has taken its simulation down with it, and
%% the caller with it (rw_sim_sup). The answer is matched by a fresh
%% reference, which the runtime finds without scanning older messages.
locked_call(Bucket, Req) ->
    Ref = make_ref(),
    Bucket ! {'$rw_call', {self(), Ref}, Req},
    receive {Ref, Reply} -> Reply end.

reply({Pid, Ref}, Reply) -> Pid ! {Ref, Reply}, ok.

-spec unlock(pid(), pid()) -> ok.
unlock(Bucket, Owner) -> gen_server:cast(Bucket, {unlock, Owner}).

%% Nothing before GVT can change any more: forget it (now and then).
-spec gvt(pid(), non_neg_integer()) -> ok.
gvt(Bucket, Gvt) -> gen_server:cast(Bucket, {gvt, Gvt}).

%%% gen_server

%% Count the time this bucket works into Stats (see rw_timewarp:stats/1).
-spec profile(pid(), counters:counters_ref()) -> ok.
profile(Bucket, Stats) -> gen_server:cast(Bucket, {profile, Stats}).

-spec init({#model{}, pos_integer()}) -> {ok, #state{}}.
init({Model, Dt}) -> {ok, #state{model = Model, dt = Dt}}.

-spec handle_call(term(), gen_server:from(), #state{}) -> {reply, term(), #state{}} | {noreply, #state{}}.
handle_call(Req, From, #state{profile = undefined} = S) -> call(Req, From, S);
handle_call(Req, From, #state{profile = Stats} = S) -> timed(Stats, fun() -> call(Req, From, S) end).

timed(Stats, Fun) ->
    T0 = reductions(),
    Result = Fun(),
    counters:add(Stats, ?TVHT_REDS, reductions() - T0),
    Result.

call({lock, Owner, Cells, Op}, From, S) ->
    %% (From is the caller and its reference, from locked_call/2)
    case free(Cells, Owner, S#state.locks) of
        true ->
            {Reply, S1} = locked_op(Owner, Op, take(Cells, Owner, S)),
            {reply, Reply, S1};
        false ->
            {noreply, S#state{waiting = S#state.waiting ++ [{From, Owner, Cells, Op}]}}
    end.

-spec handle_cast(term(), #state{}) -> {noreply, #state{}}.
handle_cast({profile, Stats}, S) -> {noreply, S#state{profile = Stats}};
handle_cast(Msg, #state{profile = undefined} = S) -> cast(Msg, S);
handle_cast(Msg, #state{profile = Stats} = S) -> timed(Stats, fun() -> cast(Msg, S) end).

cast({commit_unlock, Owner, UpTo, Ids}, S) ->
    {noreply, release(Owner, commit(Owner, UpTo, Ids, S))};
cast({unlock, Owner}, S) ->
    {noreply, release(Owner, S)};
cast({gvt, Gvt}, #state{gc_at = At} = S) when Gvt < At ->
    {noreply, S};
cast({gvt, Gvt}, #state{cells = Cells, by_body = By, contacts = C, dt = Dt} = S) ->
    Recent = fun(_, Segs) ->
                     case lists:takewhile(fun({_, Tb, _, _}) -> Tb >= Gvt end, Segs) of
                         [] -> false;
                         Kept -> {true, Kept}
                     end
             end,
    Cells1 = maps:filtermap(fun(_, ByWriter) ->
                                    case maps:filtermap(Recent, ByWriter) of
                                        Empty when map_size(Empty) =:= 0 -> false;
                                        Kept -> {true, Kept}
                                    end
                            end, Cells),
    By1 = maps:filtermap(fun(_, L) ->
                                 case [X || {T, _} = X <- L, T >= Gvt] of
                                     [] -> false;
                                     Kept -> {true, Kept}
                                 end
                         end, By),
    C1 = maps:filter(fun({T, _, _, _}, _) -> T >= Gvt end, C),
    %% sweeping costs a pass over every segment: do it every 32 substeps
    {noreply, S#state{cells = Cells1, by_body = By1, contacts = C1, gc_at = Gvt + 32 * Dt}}.

-spec handle_info(term(), #state{}) -> {noreply, #state{}}.
handle_info({'$rw_call', From, Req}, S) ->
    case handle_call(Req, From, S) of
        {reply, Reply, S1} -> reply(From, Reply), {noreply, S1};
        {noreply, _} = NoReply -> NoReply
    end;
handle_info(Msg, S) ->
    logger:warning("rw_bucket ~p: unexpected message ~p", [self(), Msg]),
    {noreply, S}.

%%% Locks

free(Cells, Owner, Locks) ->
    lists:all(fun(C) -> case Locks of
                            #{C := Other} -> Other =:= Owner;
                            _ -> true
                        end end, Cells).

take(Cells, Owner, #state{locks = Locks, held = Held} = S) ->
    S#state{locks = lists:foldl(fun(C, L) -> L#{C => Owner} end, Locks, Cells),
            held = Held#{Owner => Cells ++ maps:get(Owner, Held, [])}}.

%% Drop Owner's locks and grant waiting requests that now fit, in order.
release(Owner, S) -> grant(drop_locks(Owner, S)).

drop_locks(Owner, #state{locks = Locks, held = Held} = S) ->
    case maps:take(Owner, Held) of
        {Cells, Held1} -> S#state{locks = maps:without(Cells, Locks), held = Held1};
        error -> S
    end.

grant(#state{waiting = []} = S) -> S;
grant(#state{waiting = Waiting} = S) -> grant(Waiting, [], S).

grant([], Kept, S) -> S#state{waiting = lists:reverse(Kept)};
grant([{From, Owner, Cells, Op} = W | Rest], Kept, S) ->
    case free(Cells, Owner, S#state.locks) of
        true ->
            {Reply, S1} = locked_op(Owner, Op, take(Cells, Owner, S)),
            reply(From, Reply),
            grant(Rest, Kept, S1);
        false ->
            grant(Rest, [W | Kept], S)
    end.

%%% Operations under lock

locked_op(Owner, {probe, Write, Spans}, S) ->
    Result = probe(Write, Spans, S),
    {Result, S#state{probes = (S#state.probes)#{Owner => {Write, Spans, Result}}}};
locked_op(Owner, {probe_commit, Write, Spans, Last}, S) ->
    Result = probe(Write, Spans, S),
    {UpTo, Hits} = case Result of
                       none -> {Last, []};
                       Found -> Found
                   end,
    Ids = contact_ids(UpTo, [{Idx, OIdx} || {Idx, {OIdx, _, _, _, _}, _} <- Hits]),
    S1 = store(Owner, Write, Spans, Result, UpTo, Ids, S),
    %% The cells were free when this call took them, so freeing them again
    %% changes nothing for the requests still waiting (and granting here
    %% would re-enter grant/3, which may be running this very call).
    {{UpTo, Hits, Ids}, drop_locks(Owner, S1)};
locked_op(Owner, {delete, Idxs, R, Cells}, S) ->
    delete(Owner, Idxs, R, Cells, S).

%% The earliest LVT at which one of the written members touches another
%% body's state in one of its cells, with every contact at that LVT. Member
%% pairs meet in several cells: their windows are merged first, so that
%% each pair is checked once, and not at all when their boxes are apart.
probe({Me, _, _, Bounds} = Write, Spans, #state{cells = Cells} = S) ->
    Windows = lists:foldl(
                fun({Cell, Ta, Tb, Ms}, Acc) ->
                        case Cells of
                            %% (maps:to_list is one BIF call; maps:fold steps
                            %% an iterator in Erlang)
                            #{Cell := ByWriter} -> cell_windows(maps:to_list(ByWriter), Me, Bounds, Ta, Tb, Ms, Acc);
                            _ -> Acc
                        end
                end, #{}, Spans),
    scan_windows(maps:to_list(Windows), Write, none, S).

%% The other writers in a cell (not the prober's own earlier writes).
cell_windows([], _Me, _Bounds, _Ta, _Tb, _Ms, Acc) -> Acc;
cell_windows([{Me, _} | Rest], Me, Bounds, Ta, Tb, Ms, Acc) -> cell_windows(Rest, Me, Bounds, Ta, Tb, Ms, Acc);
cell_windows([{_, Segs} | Rest], Me, Bounds, Ta, Tb, Ms, Acc) ->
    cell_windows(Rest, Me, Bounds, Ta, Tb, Ms, segs(Segs, Bounds, Ta, Tb, Ms, Acc)).

%% A writer's segments in the cell, newest first: skip those after the
%% window, stop at the first one before it; for each that overlaps it, and
%% whose write is not apart from the prober's, the member pairs that meet
%% in time.
segs([], _Bounds, _Ta, _Tb, _Ms, Acc) -> Acc;
segs([{_, OTb, _, _} | _], _Bounds, Ta, _Tb, _Ms, Acc) when OTb < Ta -> Acc;
segs([{OTa, _, _, _} | Rest], Bounds, Ta, Tb, Ms, Acc) when OTa > Tb -> segs(Rest, Bounds, Ta, Tb, Ms, Acc);
segs([{_, _, {_, _, _, OBounds} = W, OMs} | Rest], Bounds, Ta, Tb, Ms, Acc) ->
    Acc1 = case apart(Bounds, OBounds) of
               true -> Acc;
               false -> member_windows(Ms, OMs, W, Acc)
           end,
    segs(Rest, Bounds, Ta, Tb, Ms, Acc1).

%% Windows keyed by {member, other member, other write's T0}.
member_windows([], _OMs, _W, Acc) -> Acc;
member_windows([{I, A, B} | Rest], OMs, {_, OT0, _, _} = W, Acc) ->
    Acc1 = lists:foldl(fun({O, OA, OB}, Ac) ->
                               Lo = max(A, OA),
                               Hi = min(B, OB),
                               Key = {I, O, OT0},
                               if
                                   Lo > Hi -> Ac;
                                   true ->
                                       case Ac of
                                           #{Key := {_, L, H}} -> Ac#{Key := {W, min(L, Lo), max(H, Hi)}};
                                           _ -> Ac#{Key => {W, Lo, Hi}}
                                       end
                               end
                       end, Acc, OMs),
    member_windows(Rest, OMs, W, Acc1).

scan_windows([], _Write, Best, _S) -> Best;
scan_windows([{{I, O, _}, {{_, _, OMembers, _}, Lo, Hi}} | Rest], {_, _, Members, _} = Write, Best, S) ->
    Mine = maps:get(I, Members),
    Other = maps:get(O, OMembers),
    case apart(Mine, Other) of
        true -> scan_windows(Rest, Write, Best, S);
        false -> scan_windows(Rest, Write, scan(Lo, bound(Hi, Best), Mine, Other, Best, S), S)
    end.

bound(Hi, none) -> Hi;
bound(Hi, {BT, _}) -> min(Hi, BT).

%% Two boxes (of writes or of payloads) that do not overlap: what is
%% inside cannot touch.
apart({_, _, _, _, _, A}, {_, _, _, _, _, B}) when is_tuple(A) -> apart(A, B);
apart({AX0, AY0, AZ0, AX1, AY1, AZ1}, {BX0, BY0, BZ0, BX1, BY1, BZ1}) ->
    AX1 < BX0 orelse BX1 < AX0 orelse AY1 < BY0 orelse BY1 < AY0 orelse AZ1 < BZ0 orelse BZ1 < AZ0.

%% First LVT in [Lo, Hi] at which the two bodies touch. Without CCD the
%% test is a plain distance check on the stored positions, which skips
%% the substeps at which the two are too far apart to touch yet; the
%% contact itself is computed in canonical order only on a hit.
scan(Lo, Hi, _Mine, _Other, Best, _S) when Lo > Hi -> Best;
scan(Lo, Hi, {_, _, #sphere{radius = RA}, T0A, StsA, _} = Mine,
     {_, _, #sphere{radius = RB}, T0B, StsB, _} = Other, Best, #state{dt = Dt, model = #model{ccd = false}} = S) ->
    case rw_states:first_touch(StsA, (Lo - T0A) div Dt + 1, StsB, (Lo - T0B) div Dt + 1, (Hi - Lo) div Dt,
                               RA + RB) of
        none -> Best;
        K -> hit(Lo + K * Dt, Mine, Other, Best, S)
    end;
scan(T, Hi, _Mine, _Other, Best, _S) when T > Hi -> Best;
scan(T, Hi, Mine, Other, Best, #state{model = M, dt = Dt} = S) ->
    case contact(M, entry(Mine, T, Dt), entry(Other, T, Dt)) of
        none -> scan(T + Dt, Hi, Mine, Other, Best, S);
        _ -> hit(T, Mine, Other, Best, S)
    end.

hit(T, {Idx, _, _, _, _, _} = Mine, Other, Best, #state{model = M, dt = Dt}) ->
    B = entry(Other, T, Dt),
    Hit = {Idx, B, contact(M, entry(Mine, T, Dt), B)},
    case Best of
        {T, Hits} ->
            OIdx = element(1, B),
            case lists:any(fun({I, {O, _, _, _, _}, _}) -> I =:= Idx andalso O =:= OIdx end, Hits) of
                true -> Best;
                false -> {T, [Hit | Hits]}
            end;
        _ -> {T, [Hit]}
    end.

entry({Idx, Pid, Sphere, T0, States, _}, T, Dt) ->
    I = (T - T0) div Dt + 1,
    {Idx, Pid, Sphere, rw_states:state(States, I), rw_states:displacement(States, I)}.

%% Narrowphase in canonical order: the lower index first.
contact(M, {IA, _, _, _, _} = A, {IB, _, _, _, _} = B) when IA < IB -> narrow(M, A, B);
contact(M, A, B) -> narrow(M, B, A).

narrow(#model{ccd = false}, {_, _, #sphere{radius = RA}, #st{p = PA}, _}, {_, _, #sphere{radius = RB}, #st{p = PB}, _}) ->
    rw_narrow:sphere_sphere(PA, RA, PB, RB);
narrow(#model{ccd = true}, {_, _, #sphere{radius = RA}, #st{p = PA}, DA},
       {_, _, #sphere{radius = RB}, #st{p = PB}, DB}) ->
    rw_narrow:swept_sphere_sphere(PA, DA, RA, PB, DB, RB).

commit(Owner, UpTo, Ids, #state{probes = Probes} = S) ->
    {{Write, Spans, Result}, Probes1} = maps:take(Owner, Probes),
    store(Owner, Write, Spans, Result, UpTo, Ids, S#state{probes = Probes1}).

%% Store the probed write's segments up to UpTo, and the contacts it found
%% there (in this bucket).
store(Owner, Write, Spans, Result, UpTo, Ids, #state{cells = Cells} = S) ->
    Cells1 = lists:foldl(fun({Cell, Ta, Tb, Ms}, Acc) when Ta =< UpTo ->
                                 Seg = {Ta, min(Tb, UpTo), Write, [{I, A, min(B, UpTo)} || {I, A, B} <- Ms, A =< UpTo]},
                                 case Acc of
                                     #{Cell := #{Owner := Segs} = ByW} -> Acc#{Cell := ByW#{Owner := [Seg | Segs]}};
                                     #{Cell := ByW} -> Acc#{Cell := ByW#{Owner => [Seg]}};
                                     _ -> Acc#{Cell => #{Owner => [Seg]}}
                                 end;
                            (_, Acc) -> Acc
                         end, Cells, Spans),
    S1 = S#state{cells = Cells1},
    case Result of
        {UpTo, Hits} ->
            lists:foldl(fun({Idx, {OIdx, OPid, _, _, _}, _}, Acc) ->
                                record(maps:get({Idx, OIdx}, Ids), UpTo, Idx, Owner, OIdx, OPid, Acc)
                        end, S1, Hits);
        _ ->
            S1
    end.

record(Cid, T, Idx, Detector, OIdx, Other, #state{by_body = By, contacts = C} = S) ->
    Add = fun(L) -> [{T, Cid} | L] end,
    By1 = maps:update_with(OIdx, Add, [{T, Cid}], maps:update_with(Idx, Add, [{T, Cid}], By)),
    S#state{by_body = By1, contacts = C#{Cid => {Detector, Other}}}.

%% Delete Owner's states after R in the cells Owned; return the contacts
%% its members Idxs had there after R (once each).
delete(Owner, Idxs, R, Owned, #state{cells = Cells, by_body = By, contacts = C} = S) ->
    Cells1 = lists:foldl(
               fun(Cell, Acc) ->
                       case Acc of
                           #{Cell := #{Owner := Segs} = ByW} ->
                               case truncate(Segs, R) of
                                   [] when map_size(ByW) =:= 1 -> maps:remove(Cell, Acc);
                                   [] -> Acc#{Cell := maps:remove(Owner, ByW)};
                                   Kept -> Acc#{Cell := ByW#{Owner := Kept}}
                               end;
                           _ -> Acc
                       end
               end, Cells, Owned),
    {Gone, By1} = lists:foldl(fun(Idx, {G, B}) ->
                                      case lists:partition(fun({T, _}) -> T > R end, maps:get(Idx, B, [])) of
                                          {G1, []} -> {G1 ++ G, maps:remove(Idx, B)};
                                          {G1, Kept} -> {G1 ++ G, B#{Idx => Kept}}
                                      end
                              end, {[], By}, Idxs),
    Lost = lists:ukeysort(1, [{Cid, D, O} || {_, Cid} <- Gone, {D, O} <- [maps:get(Cid, C, none)]]),
    {Lost, S#state{cells = Cells1, by_body = By1, contacts = maps:without([Cid || {_, Cid} <- Gone], C)}}.

%% A writer's segments (newest first) end at R at the latest.
truncate([{Ta, _, _, _} | Rest], R) when Ta > R -> truncate(Rest, R);
truncate([{Ta, Tb, W, Ms} | Rest], R) when Tb > R -> [{Ta, R, W, [{I, A, min(B, R)} || {I, A, B} <- Ms, A =< R]} | Rest];
truncate(Segs, _R) -> Segs.

%% Work done by this process so far (profiling counts reductions, which
%% preemption does not inflate as it does wall time).
reductions() -> element(2, erlang:process_info(self(), reductions)).
