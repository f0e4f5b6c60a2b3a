%% One dynamic body of a Time Warp simulation: a gen_statem with its own
%% Local Virtual Time, the paper's entity. Beyond the paper, an entity can
%% be a contact group: bodies in persistent contact (rw_regroup) are
%% stepped together by one of their processes, the group's leader, which
%% finds the contacts among them itself (rw_island) and meets everything
%% else through the TVHT, events and antievents, as a body on its own does.
%% The other members' processes wait meanwhile. Phases:
%%   ready    wait for the start signal (every body exists);
%%   step     integrate ahead to LVT_ub, write the states to the TVHT, stop at
%%            the first substep with contacts (Alg. 2, 5, 6);
%%   resolve  wait until the events sent for those contacts are acknowledged
%%            (Alg. 3);
%%   rollback wait until the antievents of a rollback are acknowledged
%%            (Alg. 4, 7);
%%   member   this body is stepped by its group's leader;
%%   gather   at a regroup point, wait for the bodies of the group this
%%            process is to lead.
%%
%% Groups change only at regroup points S (multiples of #sim.period) that
%% GVT has reached: the GVT process plans them a period ahead and tells
%% every entity whose group changes ({regroup, S}); such an entity rolls
%% back to S if it is past it (GVT is below S, so S is a legal rollback
%% target), says so, and stops at S, and GVT does not reach S before all
%% of them have said so. A rollback to S takes back the commit at S too,
%% as any rollback does, so GVT reaches S only once its antievents have
%% been acknowledged. Once GVT is S (no rollback can reach S or earlier,
%% and no message about a state at S or later is on its way) the old
%% leaders send each member's state and post-response velocities at S to
%% its new leader. No message ever has to follow a body to its new
%% process.
%%
%% Timeline: written holds every write to the TVHT from GVT to LVT with
%% each member's states packed in one off-heap binary (rw_states), so the
%% history of pre-response states costs the garbage collector nothing; the
%% writes cover every substep up to LVT without gaps. contacts holds, per
%% substep, the contacts with bodies outside the entity known at that
%% substep (own detections and received events), each as the member's half
%% of the pair's effect. The post-response velocities at a substep are
%% always recomputed from the pre-response states and the sorted set of all
%% their contacts (rw_island), never updated in place.
%%
%% Every event and antievent is acknowledged as soon as it has been applied
%% (after any rollback it causes has deleted its states), so no entity ever
%% waits on an entity that waits on it: the only blocking waits are for
%% acks, which always come, for bucket locks, which are taken in bucket
%% order (Lemma 1) and never held while waiting for an entity, and at a
%% regroup point for GVT, which every other entity can bring there.
-module(rw_body).
-behaviour(gen_statem).
-include("rigidwarp.hrl").
-export([start_link/3, describe/2, lvt/1]).
-export([callback_mode/0, init/1, ready/3, step/3, resolve/3, rollback/3, member/3, gather/3]).
-export_type([data/0, cid/0]).

%% Contact id: {LVT, lower idx, higher idx, unique}.
-type cid() :: {non_neg_integer(), non_neg_integer(), non_neg_integer(), reference()}.
%% A contact with a body outside the entity at some substep: the member it
%% touches, the partner, and the member's half of the pair's effect.
-type known() :: {non_neg_integer(), non_neg_integer(), rw_response:effect()}.
%% A member handed to its new leader: its state and post-response
%% velocities at the regroup point.
-type item() :: {#sphere{}, #st{}, {rw_vec:vec(), rw_vec:vec() | undefined, rw_vec:vec()}}.

-record(d, {
    sim :: #sim{},
    idx :: non_neg_integer(),                   % this process's own body
    id :: binary(),
    model :: #model{},
    fixtures :: [#fixture{}],
    dt :: pos_integer(),
    frame :: pos_integer(),                     % times in ticks (rw_scene)
    end_t :: non_neg_integer(),
    stride :: pos_integer(),
    %% the entity: the bodies this process steps, ascending idx, and where
    %% each is in that tuple (none while this body is in another's group)
    spheres = {} :: tuple(),
    idxs = [] :: [non_neg_integer()],
    pos = #{} :: #{non_neg_integer() => pos_integer()},
    island :: rw_island:island() | undefined,
    lvt = 0 :: non_neg_integer(),
    gvt = -1 :: integer(),                      % -1 until the first frame
    start :: tuple() | undefined,               % the states at LVT 0, until written
    %% a group formed at S starts from its members' post-response
    %% velocities at S, computed by their old entities
    base = none :: none | {non_neg_integer(), tuple()},
    contacts = #{} :: #{non_neg_integer() => #{cid() => known()}},
    pend_ev = #{} :: #{cid() => true},
    pend_anti = #{} :: #{cid() => true},
    ghosts = #{} :: #{cid() => true},
    committed = [] :: [non_neg_integer()],     % frame times committed, newest first
    %% substeps to integrate ahead in one step: halves on rollback, doubles
    %% (up to the stride) when a step meets nothing, so that bodies in
    %% persistent contact do not compute far ahead only to throw it away
    window = 1 :: pos_integer(),
    gc_at = 0 :: non_neg_integer(),            % next GVT at which to prune history
    wake_at = none :: none | integer(),        % the GVT rw_gvt will wake this body at
    %% the regroup points where this entity's group changes, ascending (an
    %% entity that leads a new group at S may hear of the next one before
    %% it has handed over at S)
    stop_at = [] :: [non_neg_integer()],
    %% each write: its substeps T0..UpTo, where it went, and each member's
    %% states (from T0 on, one per substep), newest first
    written = [] :: [{non_neg_integer(), non_neg_integer(), [{non_neg_integer(), pid(), [rw_hash:cell()]}],
                      tuple()}],
    %% the latest two substeps at which a member touched each outside body
    %% (the earlier one is none after a single touch), for the neighbour
    %% rule, and at how many substeps it has touched it since it last said
    %% so in #sim.met
    touched = #{} :: #{non_neg_integer() => {non_neg_integer(), non_neg_integer() | none, non_neg_integer()}},
    %% processes waiting for this one to reach an LVT: Pid => LVT
    watchers = #{} :: #{pid() => non_neg_integer()},
    watching = none :: none | {non_neg_integer(), non_neg_integer()},
    %% true while the body waits in step with no step event armed (for a
    %% partner to reach its LVT, or for GVT): a watch request cannot end
    %% that wait, so it is answered without stepping again
    idle = false :: boolean(),
    %% gathering a group at S: the old leaders to hear from, what came
    gathering = none :: none | {non_neg_integer(), [non_neg_integer()], [{non_neg_integer(), [item()]}]},
    delay = 0 :: non_neg_integer()              % test hook: max pause (ms) before TVHT work
}).
-opaque data() :: #d{}.

-define(ST_EVENTS, 1).
-define(ST_ANTIEVENTS, 2).
-define(ST_PRIMARY, 3).
-define(ST_SECONDARY, 4).
-define(ST_ROLLED_BACK, 5).
-define(ST_COMPUTED, 6).
%% reductions per stage, counted only when the simulation is profiled
-define(ST_RED_TVHT, 7).                 % hashing here, the rest by the buckets
-define(ST_RED_INTEGRATE, 8).
-define(ST_RED_ROLLBACK, 9).
-define(ST_RED_GVT, 10).
-define(ST_RED_ROLLBACK_CALLS, 11).      % bucket calls inside rollbacks, subtracted
-define(ST_STEPS, 12).                   % writes to the TVHT (one per step, any length)

%% Time Expr into counter Stage when profiling; costs one test otherwise.
-define(TIMED(D, Stage, Expr),
        case (D)#d.sim#sim.profile of
            false -> Expr;
            true -> timed((D)#d.sim#sim.stats, Stage, fun() -> Expr end)
        end).

%% A body's heap never shrinks below this many words (138 KiB): a step
%% allocates some 130 words per substep and keeps little, and a heap sized
%% to what survived the last collection collected every few dozen
%% substeps. On Cylinders 500 (one scheduler, 5 pairs run side by side)
%% this took 8.5 % less CPU, on Parallel 500 6 %; heaps of 28657 words
%% were no better within the noise, and of 46368 (362 KiB, more than
%% the cores' caches hold) made the scene a third slower.
-define(BODY_HEAP, 17711).
%% ... but all bodies' minimum heaps together at most this many words
%% (128 MiB): 1000 bodies and more get smaller ones.
-define(BODIES_HEAP, 16#1000000).

-spec start_link(#sim{}, #sphere{}, #st{}) -> gen_statem:start_ret().
start_link(#sim{n = N} = Sim, Sphere, St0) ->
    Heap = max(233, min(?BODY_HEAP, ?BODIES_HEAP div N)),
    gen_statem:start_link(?MODULE, {Sim, Sphere, St0}, [{spawn_opt, [{min_heap_size, Heap}]}]).

%% One line for the watchdog: phase, LVT and whom this body waits on.
-spec describe(atom(), data()) -> iolist().
describe(Phase, #d{idx = Idx, id = Id, lvt = Lvt, gvt = Gvt, pend_ev = PE, pend_anti = PA, idxs = Idxs}) ->
    Whom = fun(M) -> [other(Idx, Cid) || Cid <- maps:keys(M)] end,
    io_lib:format("body ~ts (idx ~b): ~p at LVT ~b (GVT ~b); ~b bodies; awaiting event acks from ~w, "
                  "antievent acks from ~w", [Id, Idx, Phase, Lvt, Gvt, length(Idxs), Whom(PE), Whom(PA)]).

-spec lvt(data()) -> non_neg_integer().
lvt(#d{lvt = Lvt}) -> Lvt.

other(Idx, {_, Idx, B, _}) -> B;
other(_Idx, {_, A, _, _}) -> A.

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> state_functions.

-spec init({#sim{}, #sphere{}, #st{}}) -> gen_statem:init_result(ready).
init({#sim{scene = #scene{model = M, substep = Dt, frame = F, stride = Stride, fixtures = Fixtures},
           end_t = End, owners = Owners} = Sim,
      #sphere{idx = Idx, id = Id} = Sphere, St0}) ->
    ets:insert(Owners, {Idx, self()}),
    D = #d{sim = Sim, idx = Idx, id = Id, model = M, fixtures = Fixtures, dt = Dt, frame = F, end_t = End,
           stride = Stride, start = {St0}},
    {ok, ready, members([Sphere], D)}.

%% This process steps Spheres from now on.
members(Spheres0, #d{model = M, fixtures = Fixtures} = D) ->
    Spheres = lists:keysort(#sphere.idx, Spheres0),
    Idxs = [I || #sphere{idx = I} <- Spheres],
    D#d{spheres = list_to_tuple(Spheres), idxs = Idxs,
        pos = maps:from_list(lists:zip(Idxs, lists:seq(1, length(Idxs)))),
        island = rw_island:new(M, Spheres, Fixtures)}.

%%% Phases

-spec step(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
%% Before the simulation starts: every body exists, none has written yet.
-spec ready(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
ready(info, go, #d{start = St0} = D) ->
    %% the initial state is written like any other, at LVT 0
    settle(write_states(0, [pack([St], D) || St <- tuple_to_list(St0)], 0, D#d{lvt = 0, start = undefined}));
ready(info, {delay, Seed, MaxMs}, D) ->
    _ = rand:seed(exsss, Seed),
    {keep_state, D#d{delay = MaxMs}};
ready(_Type, _Msg, _D) ->
    {keep_state_and_data, [postpone]}.

step(timeout, step, D0) ->
    #d{lvt = Lvt, gvt = Gvt, stride = Stride, end_t = End, dt = Dt} = D1 = read_gvt(D0),
    case regroup(min(max(Gvt, 0) + Stride, End), D1) of
        {handover, Move, D} ->
            handover(Move, D);
        {Last, Capped, D} ->
            %% A body that has passed the next sync point is not holding GVT
            %% back: it waits until it can take at least min_step/1, since
            %% one long step costs far less than many short ones.
            MinStep = min_step(D),
            case Lvt < Last andalso (Capped orelse Last - Lvt >= MinStep orelse Last =:= End
                                     orelse Lvt < next_sync(D)) of
                true ->
                    %% Neighbour rule: an entity in persistent contact with
                    %% another one (neighbour_limit/1) goes at most one
                    %% substep past it. Beyond that it could not see their
                    %% next contact, and would be rolled back when the other
                    %% one finds it. The entity with the lowest LVT is never
                    %% held, so some entity can always move.
                    %% A partner publishes its LVT only after sending the
                    %% events of its write, so the events behind the limit
                    %% read here are in our mailbox already: take them in
                    %% before stepping.
                    Limit = neighbour_limit(D),
                    case drain(D, false) of
                        {true, D2} ->
                            settle(D2);
                        {false, _} ->
                            case Limit of
                                {L, PIdx} when L =< Lvt ->
                                    {keep_state, (watch(PIdx, commit_lvt(D)))#d{idle = true}};
                                _ ->
                                    To = case Limit of none -> Last; {L, _} -> min(Last, L) end,
                                    settle(advance(Lvt, min(To, Lvt + D#d.window * Dt), D#d{watching = none}))
                            end
                    end;
                false ->
                    {keep_state, (wait(Capped, commit_lvt(D)))#d{idle = true}}
            end
    end;
step(info, {bundle, S, _, _}, #d{lvt = S, stop_at = [S | _], sim = #sim{plans = Plans}, idx = Idx} = D0) ->
    %% a new member arrives before this entity has seen GVT reach the
    %% regroup point: hand over now, and take the bundle in in gather
    D = read_gvt(D0),
    [{_, Move}] = ets:lookup(Plans, {S, Idx}),
    {next_state, gather, D1} = handover(Move, D),
    {next_state, gather, D1, [postpone]};
step(Type, Msg, D) ->
    common(Type, Msg, D).

-spec resolve(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
resolve(Type, Msg, D) -> common(Type, Msg, D).

-spec rollback(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
rollback(Type, Msg, D) -> common(Type, Msg, D).

%% Messages every phase of an entity handles; the phase that follows is
%% derived from what is still awaited.
common(info, {event, _, _, _, _, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {antievent, _, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {ack, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {gvt, _} = Msg, D) -> settle(?TIMED(D, ?ST_RED_GVT, on_message(Msg, D)));
common(info, {watch, _, _} = Msg, #d{idle = true} = D) -> {keep_state, on_message(Msg, D)};
common(info, {watch, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {reached, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {regroup, _} = Msg, D) -> settle(on_message(Msg, D));
common(timeout, step, D) ->
    settle(D);
common(info, {bundle, _, _, _} = Msg, D) ->
    %% only an entity at the regroup point, with nothing awaited, hands over
    unexpected(entity, info, Msg, D);
common(Type, Msg, D) ->
    logger:warning("rw_body ~p: unexpected ~p ~p", [D#d.idx, Type, Msg]),
    keep_state_and_data.

%% This body is stepped by another one, its group's leader. At a regroup
%% point it may be made a leader: the first member handed to it says so.
-spec member(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
member(info, {bundle, S, _, _}, #d{sim = #sim{plans = Plans}, idx = Idx} = D) ->
    [{_, #{gather := From}}] = ets:lookup(Plans, {S, Idx}),
    {next_state, gather, D#d{gathering = {S, From, []}, lvt = S, gvt = S}, [postpone]};
member(info, {regroup, S}, D) ->
    %% this body leads a group from the regroup point before S (its first
    %% member is on the way) and that group changes again at S
    {keep_state, stop_at(S, D)};
member(info, {watch, Pid, _}, #d{idx = Idx, lvt = Lvt}) ->
    %% its leader holds its LVT: let the watcher look again
    Pid ! {reached, Idx, Lvt},
    keep_state_and_data;
member(Type, Msg, D) ->
    not_stepping(member, Type, Msg, D).

%% Collecting the members of the group this process leads from the regroup
%% point on.
-spec gather(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
gather(info, {bundle, S, From, Items}, #d{gathering = {S, Expect, Got0}} = D) ->
    Got = [{From, Items} | Got0],
    case length(Got) =:= length(Expect) of
        true -> settle(form(S, lists:append([I || {_, I} <- Got]), D));
        false -> {keep_state, D#d{gathering = {S, Expect, Got}}}
    end;
gather(info, {watch, Pid, T}, D) ->
    {keep_state, on_watch(Pid, T, D)};
gather(info, {regroup, S}, #d{gathering = {Now, _, _}} = D) when S > Now ->
    %% the group this process gathers changes again at S
    {keep_state, on_regroup(S, D)};
gather(Type, Msg, D) ->
    not_stepping(gather, Type, Msg, D).

%% The rest of what a process that steps no entity (member, gather) may
%% receive: GVT and reached notices are no use to it, antievents and
%% acknowledgements are strays, and anything else is a protocol error.
not_stepping(_Phase, info, Msg, _D) when element(1, Msg) =:= gvt; element(1, Msg) =:= reached ->
    keep_state_and_data;
not_stepping(_Phase, info, Msg, D) when element(1, Msg) =:= antievent; element(1, Msg) =:= ack ->
    stray(Msg, D);
not_stepping(Phase, Type, Msg, D) ->
    unexpected(Phase, Type, Msg, D).

%% An antievent or acknowledgement about a state after the regroup point
%% that this process deleted before it handed over: the other entity
%% deleted its side first (its antievent crossed our rollback) or our
%% rollback stopped waiting for the acknowledgement. Nothing of it is here
%% any more; an antievent is acknowledged, as an entity would.
stray({antievent, Cid, _T, From}, D) ->
    send(From, {ack, anti, Cid}, D),
    keep_state_and_data;
stray({ack, _, _}, _D) ->
    keep_state_and_data.

%% No event can reach a member or a gathering leader (no state of its
%% bodies after the regroup point exists anywhere yet, and an event about
%% one it deleted arrives before the acknowledgement of its antievent,
%% which it awaited): a protocol error, which must not pass unseen.
-spec unexpected(atom(), gen_statem:event_type(), term(), #d{}) -> no_return().
unexpected(Phase, Type, Msg, #d{idx = Idx}) ->
    logger:error("rw_body ~p: ~p ~p while in ~p", [Idx, Type, Msg, Phase]),
    exit({unexpected, Phase, Msg}).

on_message({event, Cid, T, FromIdx, From, ToIdx, Effect}, D) -> on_event(Cid, T, FromIdx, From, ToIdx, Effect, D);
on_message({antievent, Cid, T, From}, D) -> on_antievent(Cid, T, From, D);
on_message({ack, event, Cid}, #d{pend_ev = P} = D) -> D#d{pend_ev = maps:remove(Cid, P)};
on_message({ack, anti, Cid}, #d{pend_anti = P} = D) -> D#d{pend_anti = maps:remove(Cid, P)};
on_message({gvt, G}, D) -> on_gvt(G, D#d{wake_at = none});
on_message({watch, Pid, T}, D) -> on_watch(Pid, T, D);
on_message({reached, _Idx, _T}, D) -> D#d{watching = none};
on_message({regroup, S}, D) -> on_regroup(S, D).

%% Take in every protocol message already in the mailbox (a timeout-0
%% step would otherwise run before them); true if there was any.
drain(D, Any) ->
    receive
        {event, _, _, _, _, _, _} = Msg -> drain(on_message(Msg, D), true);
        {antievent, _, _, _} = Msg -> drain(on_message(Msg, D), true);
        {ack, _, _} = Msg -> drain(on_message(Msg, D), true);
        {gvt, _} = Msg -> drain(on_message(Msg, D), true);
        {watch, _, _} = Msg -> drain(on_message(Msg, D), true);
        {reached, _, _} = Msg -> drain(on_message(Msg, D), true);
        {regroup, _} = Msg -> drain(on_message(Msg, D), true)
    after 0 -> {Any, D}
    end.

settle(#d{pend_anti = PA} = D) when map_size(PA) > 0 -> {next_state, rollback, D#d{idle = false}};
settle(#d{pend_ev = PE} = D) when map_size(PE) > 0 -> {next_state, resolve, D#d{idle = false}};
settle(D) -> {next_state, step, D#d{idle = false}, [{timeout, 0, step}]}.

%%% Contact groups

%% How far the entity may step (LVT_ub, Last) and whether that is capped at
%% the regroup point S where its group changes; there, once GVT is S, it
%% hands over.
regroup(Last, #d{stop_at = []} = D) -> {Last, false, D};
regroup(Last, #d{stop_at = [S | _]} = D) when S >= Last -> {Last, false, D};
regroup(_Last, #d{stop_at = [S | _], lvt = S, gvt = G, sim = #sim{plans = Plans}, idx = Idx} = D) when G >= S ->
    [{_, Move}] = ets:lookup(Plans, {S, Idx}),
    {handover, Move, D};
regroup(_Last, #d{stop_at = [S | _]} = D) -> {S, true, D}.

%% The GVT process says this entity's group changes at S: stop there,
%% rolling back to S first if it is already past (its states after S are
%% no use to the new group), and say so.
on_regroup(S, #d{lvt = Lvt} = D) ->
    stop_at(S, case Lvt > S of
                   true -> roll_back(S, D);
                   false -> D
               end).

%% Stop at the regroup point S, and tell the GVT process so.
stop_at(S, #d{sim = #sim{gvt = Gvt}, stop_at = StopAt} = D) ->
    Gvt ! {regroup_ack, S, self()},
    D#d{stop_at = lists:usort([S | StopAt])}.

%% At the regroup point S, with GVT at S: send every member's state and
%% post-response velocities at S to its new leader, then lead a new group
%% (gather) or wait as a member.
handover(#{send := Sends} = Move, #d{lvt = S, idx = Idx, spheres = Spheres, pos = Pos, watchers = W} = D0) ->
    States = state_at(S, D0),
    {Posts, D} = posts(S, States, D0),
    ByLeader = lists:foldl(fun({M, _Leader, Pid}, Acc) ->
                                   K = maps:get(M, Pos),
                                   Item = {element(K, Spheres), element(K, States), element(K, Posts)},
                                   maps:update_with(Pid, fun(L) -> [Item | L] end, [Item], Acc)
                           end, #{}, Sends),
    _ = [Pid ! {bundle, S, Idx, Items} || {Pid, Items} <- maps:to_list(ByLeader)],
    %% whoever waited for this entity looks again (its bodies move on)
    _ = [Pid ! {reached, Idx, S} || Pid <- maps:keys(W)],
    Left = D#d{spheres = {}, idxs = [], pos = #{}, island = undefined, base = none, contacts = #{},
               ghosts = #{}, committed = [], written = [], touched = #{}, watchers = #{}, watching = none,
               idle = false, wake_at = none, stop_at = tl(D#d.stop_at)},
    case Move of
        #{gather := From} -> {next_state, gather, Left#d{gathering = {S, From, []}}};
        _ -> {next_state, member, Left}
    end.

%% The group this process leads from S on, from its members' states and
%% post-response velocities at S.
form(S, Items, #d{model = M, sim = #sim{owners = Owners}} = D0) ->
    Sorted = lists:keysort(1, [{I, Item} || {#sphere{idx = I}, _, _} = Item <- Items]),
    D1 = members([Sp || {_, {Sp, _, _}} <- Sorted], D0),
    Packed = list_to_tuple([rw_states:pack([St], undefined, M#model.rotation, false) || {_, {_, St, _}} <- Sorted]),
    ets:insert(Owners, [{I, self()} || {I, _} <- Sorted]),
    %% (stop_at stays: a later regroup point may have been announced already)
    publish_lvt(D1#d{lvt = S, gvt = S, gc_at = S + D1#d.stride,
                     base = {S, list_to_tuple([Post || {_, {_, _, Post}} <- Sorted])},
                     written = [{S, S, [], Packed}], window = 1, gathering = none}).

%% The members' post-response velocities at T (GVT =< T =< LVT).
posts(T, _States, #d{base = {T, Posts}} = D) -> {Posts, D};
posts(T, States, #d{island = I} = D) ->
    {Posts, I1} = rw_island:posts(I, States, external(T, D)),
    {Posts, D#d{island = I1}}.

%% Effects of the contacts with outside bodies at T, by member.
external(_T, #d{contacts = Contacts}) when map_size(Contacts) =:= 0 -> [];
external(T, #d{contacts = Contacts}) ->
    case Contacts of
        #{T := AtT} -> [{Member, {{Partner, 0}, E}} || {Member, Partner, E} <- maps:values(AtT)];
        _ -> []
    end.

%%% Neighbour rule

-define(RECENT_SUBSTEPS, 8).

%% {Limit, Idx}: how far the slowest outside body in persistent contact
%% lets this entity go (its LVT plus one substep), or none. A partner counts
%% as in persistent contact for a few substeps after its second touch within
%% as many substeps: a single touch is most often a bounce, after which the
%% two fly apart, and holding both to one substep per write for the next few
%% substeps made Bouncing 500 write 2.6 times as often (most writes one
%% substep long) for no fewer rollbacks. Touches are remembered by partner
%% (the latest two substeps); one undone by a rollback may hold the entity
%% back a little longer than needed, never less.
neighbour_limit(#d{touched = Touched}) when map_size(Touched) =:= 0 -> none;
neighbour_limit(#d{lvt = Lvt, dt = Dt, touched = Touched, sim = #sim{lvts = Lvts}}) ->
    Since = Lvt - ?RECENT_SUBSTEPS * Dt,
    maps:fold(fun(PIdx, {T, Before, _}, Best) when T > Since, is_integer(Before),
                                                Before >= T - ?RECENT_SUBSTEPS * Dt ->
                      L = atomics:get(Lvts, rw_timewarp:lvt_slot(PIdx)) + Dt,
                      case Best of
                          {BL, BIdx} when BL < L; BL =:= L, BIdx < PIdx -> Best;
                          _ -> {L, PIdx}
                      end;
                 (_, _, Best) -> Best
              end, none, Touched).

%% Forget touches too old to matter (now and then: at each stride's GC).
forget_touches(Since, #d{touched = Touched} = D) ->
    D#d{touched = maps:filter(fun(_, {T, _, _}) -> T > Since end, Touched)}.

%% Ask the entity stepping body PIdx to tell us when it reaches our LVT
%% (once per wait).
watch(PIdx, #d{lvt = Lvt, watching = {PIdx, Lvt}} = D) -> D;
watch(PIdx, #d{lvt = Lvt, sim = #sim{owners = Owners}} = D) ->
    [{_, Pid}] = ets:lookup(Owners, PIdx),
    send(Pid, {watch, self(), Lvt}, D),
    D#d{watching = {PIdx, Lvt}}.

on_watch(Pid, T, #d{lvt = Lvt, idx = Idx} = D) when Lvt >= T ->
    Pid ! {reached, Idx, Lvt},
    D;
on_watch(Pid, T, #d{watchers = W} = D) ->
    D#d{watchers = W#{Pid => T}}.

%% Publish the LVT (at every member's slot); wake the processes waiting
%% for it.
publish_lvt(#d{sim = #sim{lvts = Lvts}, idx = Idx, idxs = Idxs, lvt = Lvt, watchers = W} = D) ->
    _ = [atomics:put(Lvts, rw_timewarp:lvt_slot(I), Lvt) || I <- Idxs],
    case map_size(W) of
        0 -> D;
        _ ->
            {Due, Later} = maps:fold(fun(Pid, T, {Du, La}) when T =< Lvt -> {[Pid | Du], La};
                                        (Pid, T, {Du, La}) -> {Du, La#{Pid => T}}
                                     end, {[], #{}}, W),
            _ = [Pid ! {reached, Idx, Lvt} || Pid <- Due],
            D#d{watchers = Later}
    end.

%%% Step: integrate from LVT to Last assuming no new contacts, write

advance(Lvt, Last, #d{spheres = Spheres, island = Island0} = D) ->
    {Passed, Steps, Island} = ?TIMED(D, ?ST_RED_INTEGRATE, chain(Lvt, state_at(Lvt, D), Last, D, Island0)),
    counters:add(D#d.sim#sim.stats, ?ST_COMPUTED, rw_states:count(hd(Steps)) * tuple_size(Spheres)),
    counters:add(D#d.sim#sim.stats, ?ST_STEPS, 1),
    D1 = write_states(Lvt + D#d.dt, Steps, Last, D#d{island = Island}),
    %% commit every frame time this step moved past
    #d{lvt = NewLvt} = D1,
    ?TIMED(D, ?ST_RED_GVT, lists:foldl(fun({T, Sts, Posts}, Acc) when T < NewLvt -> commit(T, Sts, Posts, Acc);
                                         (_, Acc) -> Acc
                                      end, D1, Passed)).

timed(Stats, Stage, Fun) ->
    T0 = reductions(),
    Result = Fun(),
    counters:add(Stats, Stage, reductions() - T0),
    Result.

%% The members' states after T up to Last (per member, rw_states:packed()
%% of one state per substep), the post-response velocities at each sync
%% point passed on the way (to commit), and the island with its neighbour
%% list. A body alone keeps its states in a list and packs them at the end
%% (a step of at most a stride); a group appends each member's states to a
%% binary as it computes them, so that the up to ?WRITE_BUDGET states of a
%% long step are never on the heap for the garbage collector to copy.
chain(T, {St}, Last, #d{spheres = {_}} = D, Island0) ->
    {Passed, States, Island} = alone(T, St, Last, D, Island0, [], []),
    {Passed, [pack(States, D)], Island};
chain(T, States, Last, #d{model = #model{rotation = Rot, ccd = Ccd}} = D, Island0) ->
    {Passed, Bins, Island} = chain(T, States, Last, D, Island0, [], [<<>> || _ <- tuple_to_list(States)]),
    {Passed, [rw_states:seal(Bin, Rot, Ccd) || Bin <- Bins], Island}.

%% States packed (with CCD, with their free displacements).
pack(States, #d{model = #model{rotation = Rot, ccd = false}}) -> rw_states:pack(States, undefined, Rot, false);
pack(States, #d{model = #model{rotation = Rot}} = D) -> rw_states:pack(States, [disp(St, D) || St <- States], Rot, true).

%% Bin with St appended (and with CCD its free displacement).
add(Bin, St, #d{model = #model{rotation = Rot}} = D) -> rw_states:append(Bin, St, disp(St, D), Rot).

%% What the packed states hold of St's free displacement: with CCD, the
%% displacement; without, nothing.
disp(_St, #d{model = #model{ccd = false}}) -> undefined;
disp(St, #d{model = M}) -> rw_integrate:free_displacement(M, St).

%% Each member's binary with its state in States appended.
add_all(_K, _States, [], _D) -> [];
add_all(K, States, [Bin | Bins], D) -> [add(Bin, element(K, States), D) | add_all(K + 1, States, Bins, D)].

%% A body on its own, the hot path of free flight.
alone(T, _St, Last, _D, Island, Passed, Acc) when T >= Last ->
    {lists:reverse(Passed), lists:reverse(Acc), Island};
alone(T, St, Last, #d{model = M, dt = Dt} = D, Island0, Passed, Acc) ->
    {{V, W, U} = Post, Island} = case D#d.base of
                                     {T, {Base}} -> {Base, Island0};
                                     _ -> rw_island:post(Island0, St, external(T, D))
                                 end,
    Next = rw_integrate:advance(M, St, V, W, U),
    Passed1 = case is_sync(T, D) of
                  true -> [{T, {St}, {Post}} | Passed];
                  false -> Passed
              end,
    alone(T + Dt, Next, Last, D, Island, Passed1, [Next | Acc]).

chain(T, _States, Last, _D, Island, Passed, Bins) when T >= Last ->
    {lists:reverse(Passed), Bins, Island};
chain(T, States, Last, #d{model = M, dt = Dt} = D, Island, Passed, Bins) ->
    {Posts, Next, Island1} =
        case D#d.base of
            {T, Base} -> {Base, rw_island:advance(M, States, Base), Island};
            _ ->
                rw_island:step(Island, States, external(T, D))
        end,
    Passed1 = case is_sync(T, D) of
                  true -> [{T, States, Posts} | Passed];
                  false -> Passed
              end,
    chain(T + Dt, Next, Last, D, Island1, Passed1, add_all(1, Next, Bins, D)).

%% A group steps at most this many body-substeps per write (16 substeps
%% for 64 members; a body alone, a stride): a write it has to truncate at
%% a contact, or that a regroup or an event rolls back, wastes every
%% member's substeps after it. On Cylinders 500 (first 2 s) efficiency
%% rose from 0.81 to 0.87 and reductions fell 3 %; 256 wrote so often
%% that it cost more than it saved.
-define(WRITE_BUDGET, 1024).

%% Write Steps (per member, its packed states from T0 on, one per substep)
%% to the TVHT under lock; stop at the first substep with contacts and send
%% the events for them. LVT becomes that substep, or Last.
write_states(T0, Steps, Last, #d{sim = Sim, written = Written} = D) ->
    Members = [member_write(K, T0, Packed, D) || {K, Packed} <- lists:zip(lists:seq(1, length(Steps)), Steps)],
    Packed = list_to_tuple([P || {_, _, P} <- Members]),
    Write = {self(), T0, maps:from_list([{Idx, Payload} || {{Idx, _, _, _, _, _} = Payload, _, _} <- Members]),
             union([Bounds || {{_, _, _, _, _, Bounds}, _, _} <- Members])},
    %% hashing the states to cells and buckets is collision-checking work
    Plan = ?TIMED(D, ?ST_RED_TVHT, plan([{Idx, cell_spans(T0, Spans, D)} || {{Idx, _, _, _, _, _}, Spans, _} <- Members],
                                        Sim)),
    maybe_delay(D),
    {UpTo, Hits, Ids} = probe_commit(Plan, Write, Last),
    Where = [{B, Pid, Cells} || {B, Pid, Cells, _} <- Plan],
    MaxWindow = max(1, min(D#d.stride div D#d.dt, ?WRITE_BUDGET div length(Steps))),
    Window = case Hits of
                 [] -> min(MaxWindow, 2 * D#d.window);
                 _ -> min(MaxWindow, max(1, 2 * ((UpTo - T0) div D#d.dt + 1)))
             end,
    D1 = D#d{lvt = UpTo, written = [{T0, UpTo, Where, Packed} | Written], window = Window},
    publish_lvt(send_events(UpTo, Hits, Ids, D1)).

%% One member's part of a write: its payload for the buckets, what
%% cell_spans/3 needs, and its packed states.
member_write(K, T0, Packed, #d{spheres = Spheres, model = M}) ->
    #sphere{idx = Idx, radius = R} = S = element(K, Spheres),
    Extents = case M#model.ccd of
                  false -> rw_states:extents(Packed);
                  true ->
                      {X, Y, Z} = rw_states:position(Packed, 1),
                      extend(1, rw_states:count(Packed), Packed, X, Y, Z, X, Y, Z)
              end,
    {{Idx, self(), S, T0, Packed, bounds(Extents, R)}, {Packed, Extents, R}, Packed}.

%% Probe the buckets of the plan in order under their locks, store the
%% states up to the first LVT with contacts (or Last), and unlock:
%% {UpTo, Hits (one per member and partner), contact ids}.
probe_commit([{_, Pid, Cells, Spans}], Write, Last) ->
    rw_bucket:probe_commit(Pid, Cells, Write, Spans, Last);
probe_commit(Plan, Write, Last) ->
    Results = [rw_bucket:lock_probe(Pid, Cells, for_bucket(Write, Spans), Spans) || {_, Pid, Cells, Spans} <- Plan],
    {UpTo, Hits} = case [R || R <- Results, R =/= none] of
                       [] -> {Last, []};
                       Found ->
                           TStar = lists:min([T || {T, _} <- Found]),
                           %% a pair found in several buckets counts once
                           {TStar, [H || {_, H} <- lists:ukeysort(1, [{{I, element(1, E)}, H}
                                                                       || {T, Hs} <- Found, T =:= TStar,
                                                                          {I, E, _} = H <- Hs])]}
                   end,
    Ids = rw_bucket:contact_ids(UpTo, [{I, element(1, E)} || {I, E, _} <- Hits]),
    [rw_bucket:commit_unlock(Pid, self(), UpTo, Ids) || {_, Pid, _, _} <- Plan],
    {UpTo, Hits, Ids}.

%% A write as one bucket of several needs it: with the payloads of only
%% the members in its cells (each bucket copies and keeps what it gets).
for_bucket({Writer, T0, Payloads, Bounds} = Write, Spans) ->
    case lists:usort([Idx || {_, _, _, Ms} <- Spans, {Idx, _, _} <- Ms]) of
        Idxs when length(Idxs) =:= map_size(Payloads) -> Write;
        Idxs -> {Writer, T0, maps:with(Idxs, Payloads), Bounds}
    end.

%% The members' pre-response states at substep T (GVT =< T =< LVT), as a
%% tuple: in the newest write that starts at or before T.
state_at(T, #d{written = Written, dt = Dt}) -> state_in(T, Written, Dt).

state_in(T, [{T0, _, _, Packed} | _], Dt) when T0 =< T ->
    I = (T - T0) div Dt + 1,
    list_to_tuple([rw_states:state(P, I) || P <- tuple_to_list(Packed)]);
state_in(T, [_ | Older], Dt) -> state_in(T, Older, Dt).

%% The box around boxes.
union([{X0, Y0, Z0, X1, Y1, Z1} | Rest]) ->
    lists:foldl(fun({A0, B0, C0, A1, B1, C1}, {U0, V0, W0, U1, V1, W1}) ->
                        {min(A0, U0), min(B0, V0), min(C0, W0), max(A1, U1), max(B1, V1), max(C1, W1)}
                end, {X0, Y0, Z0, X1, Y1, Z1}, Rest).

%% A box that holds the sphere at every state of a step (swept over each
%% substep with CCD), padded against rounding: the buckets skip the
%% narrowphase for two writes whose boxes are apart.
bounds({X0, Y0, Z0, X1, Y1, Z1}, R) ->
    Pad = R + 1.0e-9 * (R + lists:max([abs(X0), abs(Y0), abs(Z0), abs(X1), abs(Y1), abs(Z1)])),
    {X0 - Pad, Y0 - Pad, Z0 - Pad, X1 + Pad, Y1 + Pad, Z1 + Pad}.

%% The extents of the positions, swept over each substep (CCD: the packed
%% states hold the displacements).
extend(I, N, _Packed, X0, Y0, Z0, X1, Y1, Z1) when I > N -> {X0, Y0, Z0, X1, Y1, Z1};
extend(I, N, Packed, X0, Y0, Z0, X1, Y1, Z1) ->
    {X, Y, Z} = rw_states:position(Packed, I),
    {DX, DY, DZ} = rw_states:displacement(Packed, I),
    {Xa, Ya, Za} = {min(X, X + DX), min(Y, Y + DY), min(Z, Z + DZ)},
    {Xb, Yb, Zb} = {max(X, X + DX), max(Y, Y + DY), max(Z, Z + DZ)},
    extend(I + 1, N, Packed, min(X0, Xa), min(Y0, Ya), min(Z0, Za), max(X1, Xb), max(Y1, Yb), max(Z1, Zb)).

%% For each cell a member's box (swept with CCD) touches during the step,
%% the first and last substep at which it does. The box around all of the
%% step's boxes is the box of its extents padded by R (rounding is
%% monotonic). When that is the first state's box, every state keeps its
%% cells and the step is one run; when it holds at most twice as many
%% cells, one run over all of them is still cheaper than following each
%% state (a bucket tests a pair's distance at every substep anyway, so a
%% wider span adds candidates, never contacts). Otherwise (a fast body)
%% cells are enumerated only when the box changes, and a box is hashed
%% again only when it leaves the region that keeps its cells.
cell_spans(T0, {Packed, {X0, Y0, Z0, X1, Y1, Z1}, R}, #d{sim = #sim{scene = #scene{cell_size = C}}, dt = Dt}) ->
    Box = rw_hash:box(aabb(Packed, 1, R), C),
    All = rw_hash:box({{X0 - R, Y0 - R, Z0 - R}, {X1 + R, Y1 + R, Z1 + R}}, C),
    N = rw_states:count(Packed),
    case All =:= Box orelse rw_hash:box_size(All) =< 2 * rw_hash:box_size(Box) of
        true -> add_run(All, T0, T0 + (N - 1) * Dt, #{});
        false -> spans(2, N, Packed, T0 + Dt, Box, rw_hash:region(Box, C), T0, T0, {C, R, Dt}, #{})
    end.

%% State I of N of the step (at substep T) and the rest.
spans(I, N, _Packed, _T, Box, _Region, Ta, Tb, _CRDt, Acc) when I > N ->
    add_run(Box, Ta, Tb, Acc);
spans(I, N, Packed, T, Box, Region, Ta, Tb, {C, R, Dt} = CRDt, Acc) ->
    AABB = aabb(Packed, I, R),
    case rw_hash:in_region(AABB, Region) of
        true -> spans(I + 1, N, Packed, T + Dt, Box, Region, Ta, T, CRDt, Acc);
        false ->
            case rw_hash:box(AABB, C) of
                Box -> spans(I + 1, N, Packed, T + Dt, Box, Region, Ta, T, CRDt, Acc);
                New -> spans(I + 1, N, Packed, T + Dt, New, rw_hash:region(New, C), T, T, CRDt,
                             add_run(Box, Ta, Tb, Acc))
            end
    end.

add_run(Box, Ta, Tb, Acc) ->
    lists:foldl(fun(C, A) -> case A of
                                 #{C := {First, _}} -> A#{C => {First, Tb}};
                                 _ -> A#{C => {Ta, Tb}}
                             end
                end, Acc, rw_hash:box_cells(Box)).

%% The box around state I of a step (swept over its substep with CCD).
aabb(Packed, I, R) ->
    case rw_states:displacement(Packed, I) of
        undefined -> rw_shape:sphere_aabb(rw_states:position(Packed, I), R);
        Disp -> rw_shape:swept_aabb(rw_states:position(Packed, I), Disp, R)
    end.

%% The members' cell spans (Idx and Cell => {Ta, Tb}) by cell and bucket,
%% in bucket order (the lock order): [{BucketIndex, Pid, Cells, Spans}]
%% with Spans as rw_bucket:span().
plan(MemberSpans, #sim{buckets = Buckets}) ->
    NB = tuple_size(Buckets),
    ByCell = lists:foldl(fun({Idx, Spans}, Acc) ->
                                 maps:fold(fun(Cell, {Ta, Tb}, A) ->
                                                   maps:update_with(Cell, fun(L) -> [{Idx, Ta, Tb} | L] end,
                                                                    [{Idx, Ta, Tb}], A)
                                           end, Acc, Spans)
                         end, #{}, MemberSpans),
    ByBucket = maps:fold(fun(Cell, [{_, Ta0, Tb0} | _] = Ms, Acc) ->
                                 {Ta, Tb} = lists:foldl(fun({_, A, B}, {L, H}) -> {min(A, L), max(B, H)} end,
                                                        {Ta0, Tb0}, Ms),
                                 maps:update_with(rw_hash:bucket(Cell, NB), fun(L) -> [{Cell, Ta, Tb, Ms} | L] end,
                                                  [{Cell, Ta, Tb, Ms}], Acc)
                         end, #{}, ByCell),
    [{B, element(B + 1, Buckets), lists:sort([C || {C, _, _, _} <- Spans]), Spans}
     || {B, Spans} <- lists:sort(maps:to_list(ByBucket))].

send_events(_T, [], _Ids, D) -> D;
send_events(T, Hits, Ids, #d{spheres = Spheres, pos = Pos, model = M, contacts = Contacts} = D) ->
    States = state_at(T, D),
    {Mine, Pend, Touched} =
        lists:foldl(
          fun({Idx, {OIdx, OPid, OS, OSt0, _}, Contact}, {Acc, P, Tch}) ->
                  K = maps:get(Idx, Pos),
                  S = element(K, Spheres),
                  %% the pair sees both spheres' velocities after their fixture contacts
                  St = seen_by_pairs(S, element(K, States), D),
                  OSt = seen_by_pairs(OS, OSt0, D),
                  {Own, Theirs} = case Idx < OIdx of
                                      true -> rw_response:pair(M, S, St, OS, OSt, Contact);
                                      false -> swap(rw_response:pair(M, OS, OSt, S, St, Contact))
                                  end,
                  Cid = maps:get({Idx, OIdx}, Ids),
                  send(OPid, {event, Cid, T, Idx, self(), OIdx, Theirs}, D),
                  {Acc#{Cid => {Idx, OIdx, Own}}, P#{Cid => true}, touch(Idx, OIdx, T, Tch, D)}
          end, {maps:get(T, Contacts, #{}), D#d.pend_ev, D#d.touched}, Hits),
    counters:add(D#d.sim#sim.stats, ?ST_EVENTS, length(Hits)),
    D#d{contacts = Contacts#{T => Mine}, pend_ev = Pend, touched = Touched}.

seen_by_pairs(S, St, #d{model = M, fixtures = Fixtures}) ->
    rw_dynamics:after_fixtures(St, rw_dynamics:fixture_effects(M, S, St, Fixtures)).

%% Member Idx touches the outside body PIdx at T. Every ?MET substeps of
%% touching are said in #sim.met: bodies that meet that often (resting on
%% each other, or bouncing on each other again and again, as Cylinders'
%% layers do when they land) are worth one group (rw_regroup). A bounce
%% in a gas of spheres lasts one to three substeps: at 4 Bouncing 500
%% regroups a few times per run, at 2 hundreds of times (and runs 25 %
%% slower), while Cylinders 500 is as fast at 4 as at 2 and 10 % slower
%% at 8.
-define(MET, 4).

touch(Idx, PIdx, T, Touched, #d{sim = #sim{met = Met}}) ->
    case Touched of
        #{PIdx := {Last, _, _}} when Last >= T -> Touched;
        #{PIdx := {Last, _, N}} when N + 1 >= ?MET ->
            ets:insert(Met, {{min(Idx, PIdx), max(Idx, PIdx)}, T}),
            Touched#{PIdx := {T, Last, 0}};
        #{PIdx := {Last, _, N}} -> Touched#{PIdx := {T, Last, N + 1}};
        _ -> Touched#{PIdx => {T, none, 1}}
    end.

swap({A, B}) -> {B, A}.

%%% Events and antievents

on_event(Cid, T, FromIdx, From, ToIdx, Effect, #d{ghosts = Ghosts, lvt = Lvt, contacts = Contacts} = D) ->
    case maps:take(Cid, Ghosts) of
        {true, Ghosts1} ->
            %% its contact died with a state we deleted; our antievent answers it
            D#d{ghosts = Ghosts1};
        error when T > Lvt ->
            %% our state at T was deleted after the sender found the contact,
            %% and the sender deleted its own state first: its antievent for
            %% this contact follows (same sender, same order), nothing to do
            D;
        error ->
            D1 = D#d{contacts = Contacts#{T => (maps:get(T, Contacts, #{}))#{Cid => {ToIdx, FromIdx, Effect}}},
                     touched = touch(ToIdx, FromIdx, T, D#d.touched, D)},
            D2 = case T < Lvt of
                     true -> counters:add(D#d.sim#sim.stats, ?ST_PRIMARY, 1),
                             roll_back(T, D1);
                     false -> withdraw(T, D1)
                 end,
            send(From, {ack, event, Cid}, D2),
            D2
    end.

on_antievent(Cid, T, From, #d{contacts = Contacts, lvt = Lvt} = D) ->
    AtT = maps:get(T, Contacts, #{}),
    D2 = case maps:is_key(Cid, AtT) of
             true ->
                 D1 = D#d{contacts = Contacts#{T => maps:remove(Cid, AtT)},
                          pend_ev = maps:remove(Cid, D#d.pend_ev)},
                 case T < Lvt of
                     true -> counters:add(D#d.sim#sim.stats, ?ST_SECONDARY, 1),
                             roll_back(T, D1);
                     false -> withdraw(T, D1)
                 end;
             false ->
                 %% already gone with a state we deleted ourselves
                 D
         end,
    send(From, {ack, anti, Cid}, D2),
    D2.

%% Go back to R: delete the states after R from the TVHT, send antievents
%% for the contacts they had, forget commits from R on.
roll_back(R, #d{lvt = Lvt} = D) when R >= Lvt -> withdraw(R, D);
roll_back(R, D) -> ?TIMED(D, ?ST_RED_ROLLBACK, undo(R, D)).

undo(R, #d{idxs = Idxs, lvt = Lvt, dt = Dt, contacts = Contacts, sim = Sim, written = Written} = D) ->
    %% every bucket holding a state after R, with the cells it holds them in
    Where = lists:foldl(fun({B, Pid, Cells}, Acc) ->
                                maps:update_with({B, Pid}, fun(Cs) -> Cells ++ Cs end, Cells, Acc)
                        end, #{}, [X || {_, UpTo, Ws, _} <- Written, UpTo > R, X <- Ws]),
    maybe_delay(D),
    Plan = lists:sort(maps:to_list(Where)),
    %% (the buckets count their own work as TVHT; waiting is not work)
    Lost = ?TIMED(D, ?ST_RED_ROLLBACK_CALLS, lists:append([rw_bucket:lock_delete(Pid, self(), lists:usort(Cells), Idxs, R)
                                                          || {{_, Pid}, Cells} <- Plan])),
    [rw_bucket:unlock(Pid, self()) || {{_, Pid}, _} <- Plan],
    Written1 = [{T0, min(UpTo, R), Ws, P} || {T0, UpTo, Ws, P} <- Written, T0 =< R],
    %% the writes hold a state at every substep up to LVT
    counters:add(Sim#sim.stats, ?ST_ROLLED_BACK, (Lvt - R) div Dt * length(Idxs)),
    Me = self(),
    {PendAnti, Ghosts} =
        lists:foldl(
          fun({{T, _, _, _} = Cid, Detector, Other}, {PA, G}) ->
                  case maps:is_key(Cid, PA) of
                      true -> {PA, G};
                      false ->
                          Partner = case Detector of Me -> Other; _ -> Detector end,
                          send(Partner, {antievent, Cid, T, Me}, D),
                          Known = maps:is_key(Cid, maps:get(T, Contacts, #{})),
                          G1 = case Detector =/= Me andalso not Known of
                                   true -> G#{Cid => true};
                                   false -> G
                               end,
                          {PA#{Cid => true}, G1}
                  end
          end, {D#d.pend_anti, D#d.ghosts}, Lost),
    counters:add(Sim#sim.stats, ?ST_ANTIEVENTS, map_size(PendAnti) - map_size(D#d.pend_anti)),
    Keep = fun(T, _) -> T =< R end,
    withdraw(R, publish_lvt(D#d{lvt = R, contacts = maps:filter(Keep, Contacts),
                    pend_ev = #{}, pend_anti = PendAnti, ghosts = Ghosts, written = Written1,
                    window = max(1, D#d.window div 2)})).

%%% Commits (the GVT counter)

%% GVT as rw_gvt last published it.
read_gvt(#d{sim = #sim{gvt_now = Ref}} = D) -> on_gvt(atomics:get(Ref, 1), D).

%% An entity that cannot step until GVT advances asks rw_gvt to wake it
%% then: at its regroup point S (capped at S, it waits for GVT to reach S),
%% or at the earliest GVT at which it might step (step/3): when LVT_ub is
%% min_step/1 past its LVT, reaches the end, or when no sync point lies
%% between GVT and its LVT any more. Early is harmless (it asks again),
%% late would stall.
wait(true, #d{lvt = S} = D) -> wake_at(S, D);
wait(false, #d{lvt = Lvt, end_t = End} = D) when Lvt >= End -> D;
wait(false, #d{lvt = Lvt, gvt = G, stride = S, end_t = End} = D) ->
    MinStep = min_step(D),
    wake_at(max(G + 1, lists:min([Lvt + MinStep - S, End - S, last_sync(Lvt, D)])), D).

%% The last sync point at or before T.
last_sync(T, #d{frame = F, stride = S, sim = #sim{period = P}}) ->
    max(max(T div F * F, T div S * S), case P of 0 -> 0; _ -> T div P * P end).

wake_at(At, #d{wake_at = Asked} = D) when is_integer(Asked), Asked =< At -> D;   % already asked for as early
wake_at(At, D) ->
    ok = rw_gvt:wake_at(D#d.sim#sim.gvt, self(), At),
    D#d{wake_at = At}.

%% The shortest step a body takes once it has passed the next sync point:
%% three quarters of a stride. A write costs about the same however many
%% substeps it holds; half a stride made Parallel 500 write 36 substeps at a
%% time and run 10-15 % slower, a whole stride (GVT must reach the body's
%% LVT first) made bodies in contact wait.
min_step(#d{stride = S, dt = Dt}) -> max(Dt, (S * 3 div 4) div Dt * Dt).

%% The first sync point after GVT: GVT cannot advance before every body
%% has reached it.
next_sync(#d{gvt = G, sim = Sim}) -> rw_gvt:sync_after(G, Sim).

%% Bodies commit at every frame time and every multiple of the stride, so
%% that GVT can always advance far enough for LVT_ub to reach the next one,
%% and at every regroup point, where groups change once GVT is there.
is_sync(T, #d{frame = F, stride = S, end_t = End, sim = #sim{period = P}}) ->
    T rem F =:= 0 orelse T rem S =:= 0 orelse T =:= End orelse (P > 0 andalso T rem P =:= 0).

%% Commit every member's state at T: its record, and the count of bodies
%% committed at T.
commit(T, States, Posts, D) ->
    case uncommitted(T, D) of
        true -> commit_now(T, States, Posts, D);
        false -> D
    end.

%% T is a sync point after GVT that this entity has not committed yet.
uncommitted(T, D) -> T > D#d.gvt andalso is_sync(T, D) andalso not lists:member(T, D#d.committed).

commit_now(T, States, Posts, #d{sim = Sim, spheres = Spheres} = D) ->
    N = tuple_size(Spheres),
    ets:insert(Sim#sim.records, [begin
                                      #sphere{idx = Idx, id = Id} = element(K, Spheres),
                                      #st{p = P, q = Q} = element(K, States),
                                      {V, W, _U} = element(K, Posts),
                                      {{T, Idx}, {Id, P, V, Q, W}}
                                  end || K <- lists:seq(1, N)]),
    _ = case ets:update_counter(Sim#sim.counts, T, N, {T, 0}) of
            C when C =:= Sim#sim.n -> Sim#sim.gvt ! {complete, T};
            _ -> ok
        end,
    D#d{committed = [T | D#d.committed]}.

%% An entity waiting at LVT_ub (or at the end time) commits its LVT once
%% nothing is awaited there; a later event at LVT withdraws it again.
commit_lvt(#d{lvt = Lvt} = D) ->
    case uncommitted(Lvt, D) of
        true ->
            States = state_at(Lvt, D),
            {Posts, D1} = posts(Lvt, States, D),
            commit_now(Lvt, States, Posts, D1);
        false ->
            D
    end.

%% Take back every commit at or after T.
withdraw(T, #d{committed = Committed, sim = Sim, idxs = Idxs} = D) ->
    {Gone, Kept} = lists:partition(fun(C) -> C >= T end, Committed),
    N = length(Idxs),
    _ = [begin
         ets:update_counter(Sim#sim.counts, C, -N),
         [ets:delete(Sim#sim.records, {C, Idx}) || Idx <- Idxs]
     end || C <- Gone],
    D#d{committed = Kept}.

%% History before GVT can never be needed again; pruning it costs a pass,
%% so it is done once per stride.
%% (a wake-up may come after the body has read a later GVT itself)
on_gvt(G, #d{gvt = Known} = D) when G =< Known -> D;
on_gvt(G, #d{gc_at = At} = D) when G < At -> D#d{gvt = G};
on_gvt(G, #d{contacts = Contacts, committed = Committed, written = Written, stride = Stride} = D) ->
    Keep = fun(T, _) -> T >= G end,
    (forget_touches(G - ?RECENT_SUBSTEPS * D#d.dt, D))#d{gvt = G, contacts = maps:filter(Keep, Contacts),
        committed = [T || T <- Committed, T > G], written = [W || {_, UpTo, _, _} = W <- Written, UpTo >= G],
        gc_at = G + Stride}.

%% Every message to another body goes through here, so that the test hook
%% can delay it (the sender pauses, which keeps per-pair order).
send(Pid, Msg, D) ->
    maybe_delay(D),
    Pid ! Msg,
    ok.

%% Test hook: a random pause before TVHT work shuffles the order in which
%% bodies interleave (liveness and equality must not depend on it).
maybe_delay(#d{delay = 0}) -> ok;
maybe_delay(#d{delay = MaxMs}) ->
    case rand:uniform(MaxMs + 2) - 2 of
        -1 -> erlang:yield();
        0 -> ok;
        Ms -> timer:sleep(Ms)
    end.

%% Work done by this process so far (profiling counts reductions, which
%% preemption does not inflate as it does wall time).
reductions() -> element(2, erlang:process_info(self(), reductions)).
