%% One entity of a Time Warp simulation as a pure protocol machine: the
%% paper's object-centric entity with its own Local Virtual Time (Alg. 2-7).
%% handle(Message, Entity) -> {Phase, Entity, Effects}: it decides, and
%% returns what must be done as data (messages to send, a TVHT write or
%% delete, commits, the LVT to publish, whom to wake); rw_body is the
%% process that carries the effects out, in order. No message, table,
%% counter or clock is touched here.
%%
%% Beyond the paper, an entity can be a contact group: bodies in persistent
%% contact (rw_regroup) stepped together by one of their processes, the
%% group's leader, which finds the contacts among them itself (rw_island)
%% and meets everything else through the TVHT, events and antievents, as a
%% body on its own does. The other members' processes wait meanwhile.
%%
%% Phases:
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
%% Two effects are calls whose answer the machine needs before it can go
%% on: a TVHT write ({tvht_write, ...}, answered by {reply, {written, UpTo,
%% Hits, Ids, Where}}) and a TVHT delete ({tvht_delete, ...}, answered by
%% {reply, {deleted, Lost}}). Such an effect is always the last of its
%% list, and the machine handles nothing else before its answer.
%%
%% Groups change only at regroup points S (multiples of the period) that
%% GVT has reached: the GVT process plans them a period ahead and tells
%% every entity whose group changes ({regroup, S, Move}); such an entity
%% rolls back to S if it is past it (GVT is below S, so S is a legal
%% rollback target), says so, and stops at S, and GVT does not reach S
%% before all of them have said so. A rollback to S takes back the commit
%% at S too, as any rollback does, so GVT reaches S only once its
%% antievents have been acknowledged. Once GVT is S (no rollback can reach
%% S or earlier, and no message about a state at S or later is on its way)
%% the old leaders send each member's state and post-response velocities
%% at S to its new leader. No message ever has to follow a body to its new
%% process.
%%
%% Every event and antievent is acknowledged as soon as it has been applied
%% (after any rollback it causes has deleted its states), so no entity ever
%% waits on an entity that waits on it: the only blocking waits are for
%% acks, which always come, for bucket locks, which are taken in bucket
%% order (Lemma 1) and never held while waiting for an entity, and at a
%% regroup point for GVT, which every other entity can bring there.
-module(rw_entity).
-include("rigidwarp.hrl").
-export([new/5, handle/2, partners/1, idle/1, lvt/1, idx/1, describe/2]).
-export_type([entity/0, phase/0, effect/0, message/0, cid/0, addr/0]).

%% Where messages for an entity go: its process (rw_body) or, in a model
%% of the protocol, any term naming it.
-type addr() :: term().
%% Contact id: {LVT, lower idx, higher idx, unique}.
-type cid() :: rw_cells:cid().
-type phase() :: ready | step | resolve | rollback | member | gather.
%% A member handed to its new leader: its state and post-response
%% velocities at the regroup point.
-type item() :: {#sphere{}, #st{}, {rw_vec:vec(), rw_vec:vec() | undefined, rw_vec:vec()}}.

-type message() ::
        start
      | {step, Gvt :: integer(), Ahead :: pos_integer(), PartnerLvts :: [{non_neg_integer(), non_neg_integer()}]}
      | {reply, {written, non_neg_integer(), [rw_cells:hit()], rw_cells:ids(), rw_tvht_plan:where()}
              | {deleted, [{cid(), addr(), addr()}]}}
      | {event, cid(), non_neg_integer(), non_neg_integer(), addr(), non_neg_integer(), rw_response:effect()}
      | {antievent, cid(), non_neg_integer(), addr()}
      | {ack, event | anti, cid()}
      | {gvt, integer()}
      | {watch, addr(), non_neg_integer()}
      | {reached, non_neg_integer(), non_neg_integer()}
      | {regroup, non_neg_integer(), rw_regroup:move()}
      | {bundle, non_neg_integer(), non_neg_integer(), [item()], [non_neg_integer()]}.

-type effect() ::
        {send, addr(), term()}                              % to another entity or a watcher
      | {watch, Idx :: non_neg_integer(), Lvt :: non_neg_integer()}  % to the entity stepping body Idx
      | {publish_lvt, [non_neg_integer()], non_neg_integer()}
      | {commit, non_neg_integer(), [rw_commits:record()], Planned :: boolean()}  % (rw_commits:commit/4)
      | {keep, [rw_commits:record()]}                     % records committed before, to keep after all
      | {withdraw, [non_neg_integer()], [non_neg_integer()]}
      | {count, rw_stats:name(), non_neg_integer()}
      | {met, non_neg_integer(), non_neg_integer(), non_neg_integer()}
      | {wake_at, integer()}                                % ask the GVT process for {gvt, G >= At}
      | {regroup_ack, non_neg_integer()}
      | {own, [non_neg_integer()]}                          % this process steps these bodies
      | {tvht_write, non_neg_integer(), tuple(), [rw_states:packed()], non_neg_integer()}
      | {tvht_delete, rw_tvht_plan:where(), [non_neg_integer()], non_neg_integer()}.

%% What an entity knows of its simulation; the same from start to end.
-record(conf, {
    self :: addr(),
    idx :: non_neg_integer(),                   % this process's own body
    id :: binary(),
    model :: #model{},
    fixtures :: [#fixture{}],
    dt :: pos_integer(),                        % times in ticks (rw_scene)
    stride :: pos_integer(),
    end_t :: non_neg_integer(),
    cal :: rw_sync:calendar()
}).

%% An entity's state, as often changed (a copy per change: effects are
%% added to it as they are decided) ...
%% ... and as seldom changed: its make-up, the contacts that died with it,
%% its watchers and its group's changes.
-record(g, {
    %% the entity: the bodies this process steps, ascending idx, and where
    %% each is in that tuple (none while this body is in another's group)
    spheres = {} :: tuple(),
    idxs = [] :: [non_neg_integer()],
    pos = #{} :: #{non_neg_integer() => pos_integer()},
    start :: tuple() | undefined,               % the states at the start time, until written
    %% a group formed at S starts from its members' post-response
    %% velocities at S, computed by their old entities
    base = none :: none | {non_neg_integer(), tuple()},
    %% contacts that died with a state this entity deleted, whose event
    %% may still arrive: the antievent sent answers it
    ghosts = #{} :: #{cid() => true},
    gc_at = 0 :: non_neg_integer(),             % next GVT at which to prune history
    %% the regroup points where this entity's group changes, ascending (an
    %% entity that leads a new group at S may hear of the next one before
    %% it has handed over at S), and what it does at each
    stop_at = [] :: [non_neg_integer()],
    moves = #{} :: #{non_neg_integer() => rw_regroup:move()},
    %% processes waiting for this one to reach an LVT: Pid => LVT
    watchers = #{} :: #{addr() => non_neg_integer()},
    %% gathering a group at S: the old leaders to hear from, what came
    gathering = none :: none | {non_neg_integer(), [non_neg_integer()], [{non_neg_integer(), [item()]}]}
}).

-record(e, {
    conf :: #conf{},
    phase = ready :: phase(),
    island :: rw_island:island() | undefined,
    lvt = 0 :: non_neg_integer(),
    gvt = -1 :: integer(),                      % -1 until the first sync point
    timeline = rw_timeline:new() :: rw_timeline:timeline(),
    pend_ev = #{} :: #{cid() => true},
    pend_anti = #{} :: #{cid() => true},
    %% substeps a group integrates ahead in one step (window/3)
    window = 1 :: pos_integer(),
    %% how far past GVT it may step, as the last step message said: the
    %% stride, or less while the run's memory guard holds bodies back
    reach :: pos_integer(),
    wake_at = none :: none | integer(),         % the GVT the GVT process will wake this entity at
    touched = rw_neighbour:new() :: rw_neighbour:touched(),
    met_at = -1 :: integer(),                   % the latest time a member touched an outside body
    watching = none :: none | {non_neg_integer(), non_neg_integer()},
    %% true while the entity waits in step with no step due (for a partner
    %% to reach its LVT, or for GVT): a watch request cannot end that wait,
    %% so it is answered without stepping again
    idle = false :: boolean(),
    %% the rest of the work after the answer to a call effect
    cont = none :: none | {write, non_neg_integer(), [rw_states:packed()], non_neg_integer(), [rw_chain:passed()]}
                 | {undo, non_neg_integer(), then()},
    effects = [] :: [effect()],                 % newest first, while handling one message
    g = #g{} :: #g{}
}).
-opaque entity() :: #e{}.

%% What follows a rollback.
-type then() :: {ack, addr(), event | anti, cid()} | {stop_at, non_neg_integer()}.

%% A group steps at most this many body-substeps per write (a stride of 64
%% substeps up to 256 members; 16 for a pile of 1024): a write it has to
%% truncate at a contact, or that a regroup or an event rolls back, wastes
%% every member's substeps after it. A budget much smaller writes so often
%% that the writes cost more than the waste they spare: with 1024, a pile
%% of 300 wrote every 3 substeps and ran a fifth slower.
-define(WRITE_BUDGET, 16384).

%% An entity for body Sphere of Scene, starting from St0 at the calendar's start, whose
%% messages reach it at Self.
-spec new(addr(), #scene{}, rw_sync:calendar(), #sphere{}, #st{}) -> entity().
new(Self, #scene{model = M, substep = Dt, stride = Stride, fixtures = Fixtures}, Cal, #sphere{idx = Idx, id = Id} = Sphere,
    St0) ->
    Conf = #conf{self = Self, idx = Idx, id = Id, model = M, fixtures = Fixtures, dt = Dt, stride = Stride,
                 end_t = rw_sync:end_t(Cal), cal = Cal},
    members([Sphere], #e{conf = Conf, reach = Stride, g = #g{start = {St0}}}).

%% Handle one message: the phase that follows, the entity, and the effects
%% to carry out in order.
-spec handle(message(), entity()) -> {phase(), entity(), [effect()]}.
handle(Msg, #e{effects = []} = E0) ->
    case dispatch(Msg, E0) of
        #e{effects = []} = E -> {E#e.phase, E, []};
        #e{effects = [_] = Effects} = E -> {E#e.phase, E#e{effects = []}, Effects};
        #e{effects = Effects} = E -> {E#e.phase, E#e{effects = []}, lists:reverse(Effects)}
    end.

%% The outside bodies whose LVT limits how far this entity may step (the
%% neighbour rule): {step, Gvt, Ahead, Lvts} must bring their LVTs.
-spec partners(entity()) -> [non_neg_integer()].
partners(#e{lvt = Lvt, conf = #conf{dt = Dt}, touched = Touched}) -> rw_neighbour:partners(Lvt, Dt, Touched).

%% In step with no step due: it waits for a message.
-spec idle(entity()) -> boolean().
idle(#e{idle = Idle}) -> Idle.

-spec lvt(entity()) -> non_neg_integer().
lvt(#e{lvt = Lvt}) -> Lvt.

-spec idx(entity()) -> non_neg_integer().
idx(#e{conf = #conf{idx = Idx}}) -> Idx.

%% One line for the watchdog: phase, LVT and whom this entity waits on.
-spec describe(entity(), non_neg_integer()) -> iolist().
describe(#e{conf = #conf{idx = Idx, id = Id}, phase = Phase, lvt = Lvt, gvt = Gvt, pend_ev = PE, pend_anti = PA,
            g = #g{idxs = Idxs}}, Unread) ->
    Whom = fun(M) -> [other(Idx, Cid) || Cid <- maps:keys(M)] end,
    io_lib:format("body ~ts (idx ~b): ~p at LVT ~b (GVT ~b); ~b bodies; awaiting event acks from ~w, "
                  "antievent acks from ~w; ~b unread messages",
                  [Id, Idx, Phase, Lvt, Gvt, length(Idxs), Whom(PE), Whom(PA), Unread]).

other(Idx, {_, Idx, B, _}) -> B;
other(_Idx, {_, A, _, _}) -> A.

%%% Dispatch by phase

dispatch({reply, Reply}, #e{cont = Cont} = E) when Cont =/= none -> resume(Reply, Cont, E#e{cont = none});
dispatch(start, #e{phase = ready, g = #g{start = St0} = G, conf = #conf{model = M, cal = Cal}} = E) ->
    %% the initial state is written like any other, at the start time
    T0 = rw_sync:start(Cal),
    write_states(T0, [rw_chain:pack([St], M) || St <- tuple_to_list(St0)], T0, [],
                 E#e{lvt = T0, g = G#g{start = undefined}});
dispatch({step, Gvt, Ahead, Lvts}, #e{phase = step} = E) -> step(Gvt, Ahead, Lvts, E);
dispatch({bundle, S, _, _, _} = Msg, #e{phase = step, lvt = S, g = #g{stop_at = [S | _], moves = Moves}} = E) ->
    %% a new member arrives before this entity has seen GVT reach the
    %% regroup point (GVT is there, or no old leader would hand over):
    %% hand over now, and take the bundle in in gather
    dispatch(Msg, handover(maps:get(S, Moves), on_gvt(S, E)));
dispatch({watch, _, _} = Msg, #e{phase = step, idle = true} = E) -> on_message(Msg, E);
dispatch(Msg, #e{phase = Phase} = E) when Phase =:= step; Phase =:= resolve; Phase =:= rollback ->
    case element(1, Msg) of
        bundle -> unexpected(Msg, E);   % only an entity at the regroup point, with nothing awaited, hands over
        step -> settle(E);              % a step due in a phase that no longer steps
        _ -> settle_unless_calling(on_message(Msg, E))
    end;
dispatch({bundle, S, _, _, Expect} = Msg, #e{phase = member} = E) ->
    %% this body leads a group from S on: its members are on the way
    dispatch(Msg, E#e{phase = gather, lvt = S, gvt = S, g = (E#e.g)#g{gathering = {S, Expect, []}}});
dispatch({regroup, S, Move}, #e{phase = member} = E) ->
    %% this body leads a group from the regroup point before S (its first
    %% member is on the way) and that group changes again at S
    stop_at(S, add_move(S, Move, E));
dispatch({watch, Pid, _}, #e{phase = member, conf = #conf{idx = Idx}, lvt = Lvt} = E) ->
    %% its leader holds its LVT: let the watcher look again
    emit({send, Pid, {reached, Idx, Lvt}}, E);
dispatch({bundle, S, From, Items, _}, #e{phase = gather, g = #g{gathering = {S, Expect, Got0}} = G} = E) ->
    Got = [{From, Items} | Got0],
    case length(Got) =:= length(Expect) of
        true -> settle(form(S, lists:append([I || {_, I} <- Got]), E));
        false -> E#e{g = G#g{gathering = {S, Expect, Got}}}
    end;
dispatch({watch, Pid, T}, #e{phase = gather} = E) -> on_watch(Pid, T, E);
dispatch({regroup, S, _} = Msg, #e{phase = gather, g = #g{gathering = {Now, _, _}}} = E) when S > Now ->
    %% the group this process gathers changes again at S
    on_message(Msg, E);
dispatch(Msg, #e{phase = Phase} = E) when Phase =:= member; Phase =:= gather ->
    not_stepping(Msg, E);
dispatch(Msg, E) ->
    unexpected(Msg, E).

%% The rest of what a process that steps no entity (member, gather) may
%% receive: GVT and reached notices are no use to it; an antievent or
%% acknowledgement is about a state after the regroup point that this
%% process deleted before it handed over (the other entity deleted its side
%% first, or our rollback stopped waiting for the acknowledgement): nothing
%% of it is here any more, and an antievent is acknowledged, as an entity
%% would. Anything else is a protocol error.
not_stepping({gvt, _}, E) -> E;
not_stepping({reached, _, _}, E) -> E;
not_stepping({antievent, Cid, _T, From}, E) -> emit({send, From, {ack, anti, Cid}}, E);
not_stepping({ack, _, _}, E) -> E;
not_stepping(Msg, E) -> unexpected(Msg, E).

%% No event can reach a member or a gathering leader (no state of its
%% bodies after the regroup point exists anywhere yet, and an event about
%% one it deleted arrives before the acknowledgement of its antievent,
%% which it awaited): a protocol error, which must not pass unseen.
-spec unexpected(term(), #e{}) -> no_return().
unexpected(Msg, #e{phase = Phase, conf = #conf{idx = Idx}}) -> error({unexpected, Idx, Phase, Msg}).

on_message({event, Cid, T, FromIdx, From, ToIdx, Effect}, E) -> on_event(Cid, T, FromIdx, From, ToIdx, Effect, E);
on_message({antievent, Cid, T, From}, E) -> on_antievent(Cid, T, From, E);
on_message({ack, event, Cid}, #e{pend_ev = P} = E) -> E#e{pend_ev = maps:remove(Cid, P)};
on_message({ack, anti, Cid}, #e{pend_anti = P} = E) -> E#e{pend_anti = maps:remove(Cid, P)};
on_message({gvt, G}, E) -> on_gvt(G, E#e{wake_at = none});
on_message({watch, Pid, T}, E) -> on_watch(Pid, T, E);
on_message({reached, _Idx, _T}, E) -> E#e{watching = none};
on_message({regroup, S, Move}, E) -> on_regroup(S, Move, E).

%% The phase that follows from what is still awaited.
settle(#e{pend_anti = PA} = E) when map_size(PA) > 0 -> E#e{phase = rollback, idle = false};
settle(#e{pend_ev = PE} = E) when map_size(PE) > 0 -> E#e{phase = resolve, idle = false};
settle(E) -> E#e{phase = step, idle = false}.

%% (a call's answer settles the phase)
settle_unless_calling(#e{cont = none} = E) -> settle(E);
settle_unless_calling(E) -> E.

emit(Effect, #e{effects = Effects} = E) -> E#e{effects = [Effect | Effects]}.

count(_Name, 0, E) -> E;
count(Name, N, E) -> emit({count, Name, N}, E).

%% The answer to the pending call effect.
resume({written, UpTo, Hits, Ids, Where}, {write, T0, Steps, Last, Passed}, E) ->
    written(T0, Steps, Last, Passed, UpTo, Hits, Ids, Where, E);
resume({deleted, Lost}, {undo, R, Then}, E) ->
    settle(then(Then, undone(R, Lost, E))).

%%% Step (Alg. 2)

step(Gvt0, Ahead, Lvts, E0) ->
    #e{lvt = Lvt, gvt = Gvt, conf = #conf{stride = Stride, end_t = End, dt = Dt}} = E1 = on_gvt(Gvt0, E0),
    Reach = min(Stride, Ahead),
    case regroup(lvt_ub(Gvt, Reach, E1), E1#e{reach = Reach}) of
        {handover, Move, E} ->
            handover(Move, E);
        {Last, Capped, E} ->
            %% A body that has passed the next sync point is not holding GVT
            %% back: it waits until it can take at least min_step/1, since
            %% one long step costs far less than many short ones.
            case Lvt < Last andalso (Capped orelse Last - Lvt >= min_step(E) orelse Last =:= End
                                     orelse Lvt < rw_sync:after_gvt(Gvt, E#e.conf#conf.cal)) of
                true ->
                    %% the neighbour rule (rw_neighbour); Lvts were read
                    %% after the partners sent the events of their writes,
                    %% which the caller took in before this step
                    case rw_neighbour:limit(Lvts, Dt) of
                        {L, PIdx} when L =< Lvt ->
                            (watch(PIdx, commit_lvt(E)))#e{phase = step, idle = true};
                        Limit ->
                            To = case Limit of none -> Last; {L, _} -> min(Last, L) end,
                            advance(Lvt, window(Lvt, To, E), E#e{watching = none})
                    end;
                false ->
                    (wait(Capped, commit_lvt(E)))#e{phase = step, idle = true}
            end
    end.

%% LVT_ub: GVT + Reach (the stride, or less while the run's memory guard
%% holds bodies back), but never short of the first sync point after GVT:
%% the bodies that hold GVT back must always be able to reach it.
lvt_ub(Gvt, Stride, #e{conf = #conf{stride = Stride, end_t = End, cal = Cal}}) ->
    min(max(Gvt, rw_sync:start(Cal)) + Stride, End);
lvt_ub(Gvt, Reach, #e{conf = #conf{end_t = End, cal = Cal}}) ->
    min(max(max(Gvt, rw_sync:start(Cal)) + Reach, rw_sync:after_gvt(Gvt, Cal)), End).

%% How far a step from Lvt goes, To allowing. A single body goes all the
%% way: its write costs far more than the substeps it computes past a
%% contact it finds there (Bouncing 500 ran a tenth faster than with a
%% window). A group integrates at most its window ahead, which halves on
%% rollback and doubles (up to the stride) when a step meets nothing, so
%% that a pile does not compute every member far ahead only to throw it
%% away (piles ran 5 % slower without).
window(_Lvt, To, #e{g = #g{spheres = {_}}}) -> To;
window(Lvt, To, #e{window = Window, conf = #conf{dt = Dt}}) -> min(To, Lvt + Window * Dt).

%% The shortest step a body takes once it has passed the next sync point:
%% seven eighths of a stride (of its reach, while the memory guard holds
%% bodies back). A write costs about the same however many
%% substeps it holds, so shorter steps pay for more writes (with three
%% quarters, Bouncing 500 took 8 % more steps and ran 6 % slower); a whole
%% stride would make bodies in contact wait (GVT must reach the body's LVT
%% first).
min_step(#e{reach = S, conf = #conf{dt = Dt}}) -> max(Dt, (S * 7 div 8) div Dt * Dt).

%% Integrate from LVT to Last assuming no new contacts, and write.
advance(Lvt, Last, #e{g = #g{spheres = Spheres, base = Base}, island = Island0, timeline = TL,
                      conf = #conf{model = M, dt = Dt, cal = Cal}} = E) ->
    {Passed, Steps, Island} = rw_chain:run(Lvt, rw_timeline:state_at(Lvt, Dt, TL), Last, {M, Dt, Base, TL, Cal},
                                           Island0),
    E1 = count(steps, 1, count(computed_substeps, rw_states:count(hd(Steps)) * tuple_size(Spheres), E)),
    write_states(Lvt + Dt, Steps, Last, Passed, E1#e{island = Island}).

%% Write Steps (per member, its packed states from T0 on, one per substep)
%% to the TVHT under lock; the answer (written/9) stops at the first
%% substep with contacts.
write_states(T0, Steps, Last, Passed, #e{g = #g{spheres = Spheres}} = E) ->
    emit({tvht_write, T0, Spheres, Steps, Last}, E#e{cont = {write, T0, Steps, Last, Passed}}).

%% The write is stored up to UpTo, the first substep with contacts, or
%% Last: LVT becomes UpTo; send the events for the contacts there, publish
%% the LVT and commit every sync point the step moved past.
written(T0, Steps, _Last, Passed, UpTo, Hits, Ids, Where,
        #e{window = Window0, conf = #conf{stride = Stride, dt = Dt}, timeline = TL} = E) ->
    MaxWindow = max(1, min(Stride div Dt, ?WRITE_BUDGET div length(Steps))),
    Window = case Hits of
                 [] -> min(MaxWindow, 2 * Window0);
                 _ -> min(MaxWindow, max(1, 2 * ((UpTo - T0) div Dt + 1)))
             end,
    E1 = E#e{lvt = UpTo, timeline = rw_timeline:add_write(T0, UpTo, Where, list_to_tuple(Steps), TL), window = Window},
    E2 = publish_lvt(send_events(UpTo, Hits, Ids, E1)),
    settle(lists:foldl(fun({T, Sts, Posts}, Acc) when T < UpTo -> commit(T, Sts, Posts, Acc);
                          (_, Acc) -> Acc
                       end, E2, Passed)).

send_events(_T, [], _Ids, E) -> E;
send_events(T, Hits, Ids, #e{g = #g{spheres = Spheres, pos = Pos}, timeline = TL,
                             conf = #conf{self = Self, model = M, dt = Dt}} = E0) ->
    States = rw_timeline:state_at(T, Dt, TL),
    {Mine, E} =
        lists:foldl(
          fun({Idx, {OIdx, OPid, OS, OSt0, _}, Contact}, {Acc, #e{pend_ev = P} = Ei}) ->
                  K = maps:get(Idx, Pos),
                  S = element(K, Spheres),
                  %% the pair sees both spheres' velocities after their fixture contacts
                  St = seen_by_pairs(S, element(K, States), E0),
                  OSt = seen_by_pairs(OS, OSt0, E0),
                  {Own, Theirs} = case Idx < OIdx of
                                      true -> rw_response:pair(M, S, St, OS, OSt, Contact);
                                      false -> swap(rw_response:pair(M, OS, OSt, S, St, Contact))
                                  end,
                  Cid = maps:get({Idx, OIdx}, Ids),
                  Ei1 = emit({send, OPid, {event, Cid, T, Idx, Self, OIdx, Theirs}}, Ei),
                  {Acc#{Cid => {Idx, OIdx, Own}}, touch(Idx, OIdx, T, Ei1#e{pend_ev = P#{Cid => true}})}
          end, {rw_timeline:contacts_at(T, TL), E0}, Hits),
    count(events, length(Hits), E#e{timeline = rw_timeline:put_contacts(T, Mine, E#e.timeline)}).

seen_by_pairs(S, St, #e{conf = #conf{model = M, fixtures = Fixtures}}) ->
    rw_dynamics:after_fixtures(St, rw_dynamics:fixture_effects(M, S, St, Fixtures)).

swap({A, B}) -> {B, A}.

%% Member Idx touches the outside body PIdx at T (rw_neighbour); pairs
%% that meet often are said so (for rw_regroup).
touch(Idx, PIdx, T, #e{touched = Touched0, met_at = MetAt} = E) ->
    case rw_neighbour:touch(Idx, PIdx, T, Touched0) of
        {Touched, none} -> E#e{touched = Touched, met_at = max(MetAt, T)};
        {Touched, {A, B, At}} -> emit({met, A, B, At}, E#e{touched = Touched, met_at = max(MetAt, T)})
    end.

%% Publish the LVT (at every member's slot); wake the processes waiting
%% for it.
publish_lvt(#e{g = #g{idxs = Idxs, watchers = W} = G, lvt = Lvt, conf = #conf{idx = Idx}} = E0) ->
    E = emit({publish_lvt, Idxs, Lvt}, E0),
    case map_size(W) of
        0 -> E;
        _ ->
            {Due, Later} = maps:fold(fun(Pid, T, {Du, La}) when T =< Lvt -> {[Pid | Du], La};
                                        (Pid, T, {Du, La}) -> {Du, La#{Pid => T}}
                                     end, {[], #{}}, W),
            lists:foldl(fun(Pid, Acc) -> emit({send, Pid, {reached, Idx, Lvt}}, Acc) end, E#e{g = G#g{watchers = Later}},
                        Due)
    end.

%%% The neighbour rule's waits

%% Ask the entity stepping body PIdx to tell us when it reaches our LVT
%% (once per wait).
watch(PIdx, #e{lvt = Lvt, watching = {PIdx, Lvt}} = E) -> E;
watch(PIdx, #e{lvt = Lvt} = E) -> emit({watch, PIdx, Lvt}, E#e{watching = {PIdx, Lvt}}).

on_watch(Pid, T, #e{lvt = Lvt, conf = #conf{idx = Idx}} = E) when Lvt >= T ->
    emit({send, Pid, {reached, Idx, Lvt}}, E);
on_watch(Pid, T, #e{g = #g{watchers = W} = G} = E) ->
    E#e{g = G#g{watchers = W#{Pid => T}}}.

%%% Events and antievents

on_event(Cid, T, FromIdx, From, ToIdx, Effect, #e{g = #g{ghosts = Ghosts} = G, lvt = Lvt, timeline = TL} = E) ->
    case maps:take(Cid, Ghosts) of
        {true, Ghosts1} ->
            %% its contact died with a state we deleted; our antievent answers it
            E#e{g = G#g{ghosts = Ghosts1}};
        error when T > Lvt ->
            %% our state at T was deleted after the sender found the contact,
            %% and the sender deleted its own state first: its antievent for
            %% this contact follows (same sender, same order), nothing to do
            E;
        error ->
            AtT = (rw_timeline:contacts_at(T, TL))#{Cid => {ToIdx, FromIdx, Effect}},
            E1 = touch(ToIdx, FromIdx, T, E#e{timeline = rw_timeline:put_contacts(T, AtT, TL)}),
            Ack = {ack, From, event, Cid},
            case T < Lvt of
                true -> roll_back(T, Ack, count(primary_rollbacks, 1, E1));
                false -> then(Ack, withdraw(T, E1))
            end
    end.

on_antievent(Cid, T, From, #e{lvt = Lvt, timeline = TL} = E) ->
    AtT = rw_timeline:contacts_at(T, TL),
    Ack = {ack, From, anti, Cid},
    case maps:is_key(Cid, AtT) of
        true ->
            E1 = E#e{timeline = rw_timeline:put_contacts(T, maps:remove(Cid, AtT), TL),
                     pend_ev = maps:remove(Cid, E#e.pend_ev)},
            case T < Lvt of
                true -> roll_back(T, Ack, count(secondary_rollbacks, 1, E1));
                false -> then(Ack, withdraw(T, E1))
            end;
        false ->
            %% already gone with a state we deleted ourselves
            then(Ack, E)
    end.

then({ack, To, Kind, Cid}, E) -> emit({send, To, {ack, Kind, Cid}}, E);
then({stop_at, S}, E) -> stop_at(S, E).

%% Go back to R: delete the states after R from the TVHT (a call; undone/3
%% goes on with its answer), send antievents for the contacts they had,
%% forget commits from R on; then Then.
roll_back(R, Then, #e{lvt = Lvt} = E) when R >= Lvt -> then(Then, withdraw(R, E));
roll_back(R, Then, #e{g = #g{idxs = Idxs}, timeline = TL} = E) ->
    emit({tvht_delete, rw_timeline:where_after(R, TL), Idxs, R}, E#e{cont = {undo, R, Then}}).

undone(R, Lost, #e{g = #g{idxs = Idxs} = G, lvt = Lvt, timeline = TL, conf = #conf{self = Me, dt = Dt}} = E0) ->
    %% the writes hold a state at every substep up to LVT
    E1 = count(rolled_back_substeps, (Lvt - R) div Dt * length(Idxs), E0),
    {PendAnti, Ghosts, E2} =
        lists:foldl(
          fun({{T, _, _, _} = Cid, Detector, Other}, {PA, Gh, Ei}) ->
                  case maps:is_key(Cid, PA) of
                      true -> {PA, Gh, Ei};
                      false ->
                          Partner = case Detector of Me -> Other; _ -> Detector end,
                          Known = maps:is_key(Cid, rw_timeline:contacts_at(T, TL)),
                          G1 = case Detector =/= Me andalso not Known of
                                   true -> Gh#{Cid => true};
                                   false -> Gh
                               end,
                          {PA#{Cid => true}, G1, emit({send, Partner, {antievent, Cid, T, Me}}, Ei)}
                  end
          end, {E1#e.pend_anti, G#g.ghosts, E1}, Lost),
    E3 = count(antievents, map_size(PendAnti) - map_size(E1#e.pend_anti), E2),
    withdraw(R, publish_lvt(E3#e{lvt = R, timeline = rw_timeline:truncate(R, TL), pend_ev = #{}, pend_anti = PendAnti,
                                 g = G#g{ghosts = Ghosts}, window = max(1, E3#e.window div 2)})).

%%% Commits (the GVT counter)

%% An entity that cannot step until GVT advances asks the GVT process to
%% wake it then: at its regroup point S (capped at S, it waits for GVT to
%% reach S), or at the earliest GVT at which it might step (step/4): when
%% LVT_ub is min_step/1 past its LVT, reaches the end, or when no sync
%% point lies between GVT and its LVT any more. Early is harmless (it asks
%% again), late would stall.
wait(true, #e{lvt = S} = E) -> wake_at(S, E);
wait(false, #e{lvt = Lvt, conf = #conf{end_t = End}} = E) when Lvt >= End -> E;
wait(false, #e{lvt = Lvt, gvt = G, reach = S, conf = #conf{end_t = End, cal = Cal}} = E) ->
    wake_at(max(G + 1, lists:min([Lvt + min_step(E) - S, End - S, rw_sync:last_before(Lvt, Cal)])), E).

wake_at(At, #e{wake_at = Asked} = E) when is_integer(Asked), Asked =< At -> E;   % already asked for as early
wake_at(At, E) -> emit({wake_at, At}, E#e{wake_at = At}).

%% Commit every member's state at sync point T: its frame record and its
%% pre-response velocities (with the frame's position and orientation, the
%% whole state a run resumed from T starts with), keyed by time and body.
commit(T, States, Posts, E) ->
    case uncommitted(T, E) of
        true -> commit_now(T, States, Posts, E);
        false -> E
    end.

%% T is a sync point after GVT that this entity has not committed yet.
uncommitted(T, #e{gvt = G, timeline = TL, conf = #conf{cal = Cal}}) ->
    T > G andalso rw_sync:is_sync(T, Cal) andalso not rw_timeline:is_committed(T, TL).

commit_now(T, States, Posts, #e{timeline = TL} = E) ->
    emit({commit, T, records(T, States, Posts, E), planned(T, E)}, E#e{timeline = rw_timeline:commit(T, TL)}).

records(T, States, Posts, #e{g = #g{spheres = Spheres}}) ->
    [begin
         #sphere{idx = Idx, id = Id} = element(K, Spheres),
         #st{p = P, v = V0, q = Q, w = W0} = element(K, States),
         {V, W, _U} = element(K, Posts),
         rw_commits:record(T, Idx, Id, P, V, Q, W, {V0, W0})
     end || K <- lists:seq(1, tuple_size(Spheres))].

%% May the regroup plan at T read this entity's records there? It reads
%% those of every member of a group (a group's, or a body's that joins one
%% at T) and of the bodies of pairs that met in the period before T: any
%% pair that met since a record was kept without it (a partner's late
%% touch) the plan leaves out until the next regroup point.
planned(T, #e{g = #g{spheres = Spheres, moves = Moves}, met_at = MetAt, conf = #conf{cal = Cal}}) ->
    case rw_sync:period(Cal) of
        0 -> false;
        P -> T rem P =:= 0 andalso (tuple_size(Spheres) > 1 orelse is_map_key(T, Moves) orelse MetAt >= T - P)
    end.

%% An entity waiting at LVT_ub (or at the end time) commits its LVT once
%% nothing is awaited there; a later event at LVT withdraws it again.
commit_lvt(#e{lvt = Lvt, timeline = TL, conf = #conf{dt = Dt}} = E) ->
    case uncommitted(Lvt, E) of
        true ->
            States = rw_timeline:state_at(Lvt, Dt, TL),
            {Posts, E1} = posts(Lvt, States, E),
            commit_now(Lvt, States, Posts, E1);
        false ->
            E
    end.

%% Take back every commit at or after T.
withdraw(T, #e{timeline = TL, g = #g{idxs = Idxs}} = E) ->
    case rw_timeline:withdraw(T, TL) of
        {[], _} -> E;
        {Gone, TL1} -> emit({withdraw, Gone, Idxs}, E#e{timeline = TL1})
    end.

%% History before GVT can never be needed again; pruning it costs a pass,
%% so it is done once per stride (per reach, while the memory guard holds
%% bodies back: the history is to shrink then). (A wake-up may come after
%% the entity has read a later GVT itself.)
on_gvt(G, #e{gvt = Known} = E) when G =< Known -> E;
on_gvt(G, #e{g = #g{gc_at = At}} = E) when G < At -> E#e{gvt = G};
on_gvt(G, #e{timeline = TL, touched = Touched, g = Grp, reach = Reach, conf = #conf{dt = Dt}} = E) ->
    E#e{gvt = G, touched = rw_neighbour:forget(G, Dt, Touched), timeline = rw_timeline:prune(G, TL),
        g = Grp#g{gc_at = G + Reach}}.

%%% Contact groups

%% This process steps Spheres from now on.
members(Spheres0, #e{conf = #conf{model = M, fixtures = Fixtures}, g = G} = E) ->
    Spheres = lists:keysort(#sphere.idx, Spheres0),
    Idxs = [I || #sphere{idx = I} <- Spheres],
    E#e{g = G#g{spheres = list_to_tuple(Spheres), idxs = Idxs,
                pos = maps:from_list(lists:zip(Idxs, lists:seq(1, length(Idxs))))},
        island = rw_island:new(M, Spheres, Fixtures)}.

%% How far the entity may step (LVT_ub, Last) and whether that is capped at
%% the regroup point S where its group changes; there, once GVT is S, it
%% hands over.
regroup(Last, #e{g = #g{stop_at = []}} = E) -> {Last, false, E};
regroup(Last, #e{g = #g{stop_at = [S | _]}} = E) when S >= Last -> {Last, false, E};
regroup(_Last, #e{g = #g{stop_at = [S | _], moves = Moves}, lvt = S, gvt = G} = E) when G >= S ->
    {handover, maps:get(S, Moves), E};
regroup(_Last, #e{g = #g{stop_at = [S | _]}} = E) -> {S, true, E}.

%% The GVT process says this entity's group changes at S: stop there,
%% rolling back to S first if it is already past (its states after S are
%% no use to the new group), and say so.
on_regroup(S, Move, #e{lvt = Lvt} = E0) ->
    E = add_move(S, Move, E0),
    case Lvt > S of
        true -> roll_back(S, {stop_at, S}, E);
        false -> stop_at(S, keep_at(S, E))
    end.

%% An entity at S that has committed S already, maybe without keeping its
%% records: the plan at S reads them (it joins a group there).
keep_at(S, #e{lvt = S, timeline = TL, conf = #conf{dt = Dt}} = E) ->
    case rw_timeline:is_committed(S, TL) of
        true ->
            States = rw_timeline:state_at(S, Dt, TL),
            {Posts, E1} = posts(S, States, E),
            emit({keep, records(S, States, Posts, E1)}, E1);
        false ->
            E
    end;
keep_at(_S, E) -> E.

%% Stop at the regroup point S, and tell the GVT process so.
stop_at(S, #e{g = #g{stop_at = StopAt} = G} = E) ->
    emit({regroup_ack, S}, E#e{g = G#g{stop_at = lists:usort([S | StopAt])}}).

%% What to do at regroup point S.
add_move(S, Move, #e{g = #g{moves = Moves} = G} = E) -> E#e{g = G#g{moves = Moves#{S => Move}}}.

%% At the regroup point S, with GVT at S: send every member's state and
%% post-response velocities at S to its new leader, then lead a new group
%% (gather) or wait as a member.
handover(#{send := Sends, expect := Expect} = Move,
         #e{lvt = S, g = #g{spheres = Spheres, pos = Pos, watchers = W, moves = Moves, stop_at = [_ | StopAt]} = G,
            timeline = TL, conf = #conf{idx = Idx, dt = Dt}} = E0) ->
    States = rw_timeline:state_at(S, Dt, TL),
    {Posts, E} = posts(S, States, E0),
    ByLeader = lists:foldl(fun({M, Leader, Pid}, Acc) ->
                                   K = maps:get(M, Pos),
                                   Item = {element(K, Spheres), element(K, States), element(K, Posts)},
                                   maps:update_with(Pid, fun({L, Items}) -> {L, [Item | Items]} end, {Leader, [Item]},
                                                    Acc)
                           end, #{}, Sends),
    E1 = lists:foldl(fun({Pid, {Leader, Items}}, Acc) ->
                             emit({send, Pid, {bundle, S, Idx, Items, maps:get(Leader, Expect)}}, Acc)
                     end, E, maps:to_list(ByLeader)),
    %% whoever waited for this entity looks again (its bodies move on)
    E2 = lists:foldl(fun(Pid, Acc) -> emit({send, Pid, {reached, Idx, S}}, Acc) end, E1, maps:keys(W)),
    Left = G#g{spheres = {}, idxs = [], pos = #{}, base = none, ghosts = #{}, watchers = #{}, stop_at = StopAt,
               moves = maps:remove(S, Moves)},
    E3 = E2#e{island = undefined, timeline = rw_timeline:new(), touched = rw_neighbour:new(), watching = none,
              idle = false, wake_at = none},
    case Move of
        #{gather := From} -> E3#e{phase = gather, g = Left#g{gathering = {S, From, []}}};
        _ -> E3#e{phase = member, g = Left}
    end.

%% The group this process leads from S on, from its members' states and
%% post-response velocities at S.
form(S, Items, #e{conf = #conf{model = M, stride = Stride}} = E0) ->
    Sorted = lists:keysort(1, [{I, Item} || {#sphere{idx = I}, _, _} = Item <- Items]),
    E1 = members([Sp || {_, {Sp, _, _}} <- Sorted], E0),
    Packed = list_to_tuple([rw_states:pack([St], undefined, M#model.rotation, false) || {_, {_, St, _}} <- Sorted]),
    E2 = emit({own, [I || {I, _} <- Sorted]}, E1),
    %% (stop_at stays: a later regroup point may have been announced
    %% already.) Its first step is 4 substeps: in a pile that changes at
    %% every regroup point, steps of 1 and 2 substeps wrote more often than
    %% they saved (Pile 300 3 %, Heap 500 5 % faster with 4), and 8 or more
    %% lose to contacts with bodies landing on it (Heap 500 5 % slower).
    G = E2#e.g,
    publish_lvt(E2#e{lvt = S, gvt = S, timeline = rw_timeline:add_write(S, S, [], Packed, rw_timeline:new()), window = 4,
                     g = G#g{gc_at = S + Stride, base = {S, list_to_tuple([Post || {_, {_, _, Post}} <- Sorted])},
                             gathering = none}}).

%% The members' post-response velocities at T (GVT =< T =< LVT).
posts(T, _States, #e{g = #g{base = {T, Posts}}} = E) -> {Posts, E};
posts(T, States, #e{island = I, timeline = TL} = E) ->
    {Posts, I1} = rw_island:posts(I, States, rw_timeline:external(T, TL)),
    {Posts, E#e{island = I1}}.
