%% One dynamic body of a Time Warp simulation (the paper's entity): a
%% gen_statem with its own Local Virtual Time and the phases
%%   ready    wait for the start signal (every body exists);
%%   step     integrate ahead to LVT_ub, write the states to the TVHT, stop at
%%            the first substep with contacts (Alg. 2, 5, 6);
%%   resolve  wait until the events sent for those contacts are acknowledged
%%            (Alg. 3);
%%   rollback wait until the antievents of a rollback are acknowledged
%%            (Alg. 4, 7).
%%
%% Timeline: written holds every write to the TVHT from GVT to LVT with
%% its states packed in one off-heap binary (rw_states), so the history of
%% pre-response states costs the body's garbage collector nothing; the
%% writes cover every substep up to LVT without gaps. contacts holds, per substep, the contacts with
%% other bodies known at that substep (own detections and received events),
%% each as this body's half of the pair's effect. The post-response velocity
%% at a substep is always recomputed from the pre-response state and the
%% sorted set of all its contacts (rw_dynamics), never updated in place.
%%
%% Every event and antievent is acknowledged as soon as it has been applied
%% (after any rollback it causes has deleted its states), so no body ever
%% waits on a body that waits on it: the only blocking waits are for acks,
%% which always come, and for bucket locks, which are taken in bucket order
%% (Lemma 1) and never held while waiting for a body.
-module(rw_body).
-behaviour(gen_statem).
-include("rigidwarp.hrl").
-export([start_link/3, describe/2, lvt/1]).
-export([callback_mode/0, init/1, ready/3, step/3, resolve/3, rollback/3]).
-export_type([data/0, cid/0]).

%% Contact id: {LVT, lower idx, higher idx, unique}.
-type cid() :: {non_neg_integer(), non_neg_integer(), non_neg_integer(), reference()}.

-record(d, {
    sim :: #sim{},
    sphere :: #sphere{},
    idx :: non_neg_integer(),
    model :: #model{},
    dt :: pos_integer(),
    frame :: pos_integer(),                     % times in ticks (rw_scene)
    end_t :: non_neg_integer(),
    stride :: pos_integer(),
    lvt = 0 :: non_neg_integer(),
    gvt = -1 :: integer(),                      % -1 until the first frame
    start :: #st{},                             % the state at LVT 0, until written
    contacts = #{} :: #{non_neg_integer() => #{cid() => {non_neg_integer(), rw_response:effect()}}},
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
    %% each write: its substeps T0..UpTo, where it went, and its states
    %% (from T0 on, one per substep), newest first
    written = [] :: [{non_neg_integer(), non_neg_integer(), [{non_neg_integer(), pid(), [rw_hash:cell()]}],
                      rw_states:packed()}],
    %% bodies touched recently, for the neighbour rule (see step/3)
    partners = #{} :: #{non_neg_integer() => pid()},
    %% the latest two substeps at which this body touched each partner
    %% (the earlier one is none after a single touch)
    touched = #{} :: #{non_neg_integer() => {non_neg_integer(), non_neg_integer() | none}},
    %% bodies waiting for this one to reach an LVT: Pid => LVT
    watchers = #{} :: #{pid() => non_neg_integer()},
    watching = none :: none | {non_neg_integer(), non_neg_integer()},
    %% true while the body waits in step with no step event armed (for a
    %% partner to reach its LVT, or for GVT): a watch request cannot end
    %% that wait, so it is answered without stepping again
    idle = false :: boolean(),
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

-spec start_link(#sim{}, #sphere{}, #st{}) -> gen_statem:start_ret().
start_link(Sim, Sphere, St0) -> gen_statem:start_link(?MODULE, {Sim, Sphere, St0}, []).

%% One line for the watchdog: phase, LVT and whom this body waits on.
-spec describe(atom(), data()) -> iolist().
describe(Phase, #d{idx = Idx, sphere = #sphere{id = Id}, lvt = Lvt, gvt = Gvt, pend_ev = PE, pend_anti = PA}) ->
    Whom = fun(M) -> [other(Idx, Cid) || Cid <- maps:keys(M)] end,
    io_lib:format("body ~ts (idx ~b): ~p at LVT ~b (GVT ~b); awaiting event acks from ~w, "
                  "antievent acks from ~w", [Id, Idx, Phase, Lvt, Gvt, Whom(PE), Whom(PA)]).

-spec lvt(data()) -> non_neg_integer().
lvt(#d{lvt = Lvt}) -> Lvt.

other(Idx, {_, Idx, B, _}) -> B;
other(_Idx, {_, A, _, _}) -> A.

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> state_functions.

-spec init({#sim{}, #sphere{}, #st{}}) -> gen_statem:init_result(ready).
init({#sim{scene = #scene{model = M, substep = Dt, frame = F, stride = Stride}, end_t = End} = Sim,
      #sphere{idx = Idx} = Sphere, St0}) ->
    {ok, ready, #d{sim = Sim, sphere = Sphere, idx = Idx, model = M, dt = Dt, frame = F,
                   end_t = End, stride = Stride, start = St0}}.

%%% Phases

-spec step(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
%% Before the simulation starts: every body exists, none has written yet.
-spec ready(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
ready(info, go, #d{start = St0} = D) ->
    %% the initial state is written like any other, at LVT 0
    settle(write_states(0, [St0], 0, D#d{lvt = 0}));
ready(info, {delay, Seed, MaxMs}, D) ->
    _ = rand:seed(exsss, Seed),
    {keep_state, D#d{delay = MaxMs}};
ready(_Type, _Msg, _D) ->
    {keep_state_and_data, [postpone]}.

step(timeout, step, D0) ->
    #d{lvt = Lvt, gvt = Gvt, stride = Stride, end_t = End, dt = Dt} = D = read_gvt(D0),
    Last = min(max(Gvt, 0) + Stride, End),
    %% A body that has passed the next sync point is not holding GVT back:
    %% it waits until it can take at least min_step/1, since one long
    %% step costs far less than many short ones.
    MinStep = min_step(D),
    case Lvt < Last andalso (Last - Lvt >= MinStep orelse Last =:= End orelse Lvt < next_sync(D)) of
        true ->
            %% Neighbour rule: a body in persistent contact with another
            %% one (neighbour_limit/1) goes at most one substep past it. Beyond that it
            %% could not see their next contact, and would be rolled back
            %% when the other body finds it. The body with the lowest LVT is
            %% never held, so some body can always move.
            %% A partner publishes its LVT only after sending the events of
            %% its write, so the events behind the limit read here are in
            %% our mailbox already: take them in before stepping.
            Limit = neighbour_limit(D),
            case drain(D, false) of
                {true, D1} ->
                    settle(D1);
                {false, _} ->
                    case Limit of
                        {L, PIdx, PPid} when L =< Lvt ->
                            {keep_state, (watch(PIdx, PPid, commit_lvt(D)))#d{idle = true}};
                        _ ->
                            To = case Limit of none -> Last; {L, _, _} -> min(Last, L) end,
                            settle(advance(Lvt, min(To, Lvt + D#d.window * Dt), D#d{watching = none}))
                    end
            end;
        false -> {keep_state, (wake_me(commit_lvt(D)))#d{idle = true}}
    end;
step(Type, Msg, D) ->
    common(Type, Msg, D).

-spec resolve(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
resolve(Type, Msg, D) -> common(Type, Msg, D).

-spec rollback(gen_statem:event_type(), term(), #d{}) -> gen_statem:event_handler_result(atom()).
rollback(Type, Msg, D) -> common(Type, Msg, D).

%% Messages every phase handles; the phase that follows is derived from
%% what is still awaited.
common(info, {event, _, _, _, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {antievent, _, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {ack, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {gvt, _} = Msg, D) -> settle(?TIMED(D, ?ST_RED_GVT, on_message(Msg, D)));
common(info, {watch, _, _} = Msg, #d{idle = true} = D) -> {keep_state, on_message(Msg, D)};
common(info, {watch, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(info, {reached, _, _} = Msg, D) -> settle(on_message(Msg, D));
common(timeout, step, D) ->
    settle(D);
common(Type, Msg, D) ->
    logger:warning("rw_body ~p: unexpected ~p ~p", [D#d.idx, Type, Msg]),
    keep_state_and_data.

on_message({event, Cid, T, FromIdx, From, Effect}, D) -> on_event(Cid, T, FromIdx, From, Effect, D);
on_message({antievent, Cid, T, From}, D) -> on_antievent(Cid, T, From, D);
on_message({ack, event, Cid}, #d{pend_ev = P} = D) -> D#d{pend_ev = maps:remove(Cid, P)};
on_message({ack, anti, Cid}, #d{pend_anti = P} = D) -> D#d{pend_anti = maps:remove(Cid, P)};
on_message({gvt, G}, D) -> on_gvt(G, D#d{wake_at = none});
on_message({watch, Pid, T}, D) -> on_watch(Pid, T, D);
on_message({reached, _Idx, _T}, D) -> D#d{watching = none}.

%% Take in every protocol message already in the mailbox (a timeout-0
%% step would otherwise run before them); true if there was any.
drain(D, Any) ->
    receive
        {event, _, _, _, _, _} = Msg -> drain(on_message(Msg, D), true);
        {antievent, _, _, _} = Msg -> drain(on_message(Msg, D), true);
        {ack, _, _} = Msg -> drain(on_message(Msg, D), true);
        {gvt, _} = Msg -> drain(on_message(Msg, D), true);
        {watch, _, _} = Msg -> drain(on_message(Msg, D), true);
        {reached, _, _} = Msg -> drain(on_message(Msg, D), true)
    after 0 -> {Any, D}
    end.

settle(#d{pend_anti = PA} = D) when map_size(PA) > 0 -> {next_state, rollback, D#d{idle = false}};
settle(#d{pend_ev = PE} = D) when map_size(PE) > 0 -> {next_state, resolve, D#d{idle = false}};
settle(D) -> {next_state, step, D#d{idle = false}, [{timeout, 0, step}]}.

%%% Neighbour rule

-define(RECENT_SUBSTEPS, 8).

%% {Limit, Idx, Pid}: how far the slowest body in persistent contact lets
%% this one go (its LVT plus one substep), or none. A partner counts as in
%% persistent contact for a few substeps after its second touch within as
%% many substeps: a single touch is most often a bounce, after which the two
%% fly apart, and holding both bodies to one substep per write for the next
%% few substeps made Bouncing 500 write 2.6 times as often (most writes one
%% substep long) for no fewer rollbacks. Touches are remembered by partner
%% (the latest two substeps); one undone by a rollback may hold the body
%% back a little longer than needed, never less.
neighbour_limit(#d{touched = Touched}) when map_size(Touched) =:= 0 -> none;
neighbour_limit(#d{lvt = Lvt, dt = Dt, touched = Touched, partners = Partners, sim = #sim{lvts = Lvts}}) ->
    Since = Lvt - ?RECENT_SUBSTEPS * Dt,
    maps:fold(fun(PIdx, {T, Before}, Best) when T > Since, is_integer(Before),
                                                Before >= T - ?RECENT_SUBSTEPS * Dt ->
                      L = atomics:get(Lvts, rw_timewarp:lvt_slot(PIdx)) + Dt,
                      case Best of
                          {BL, BIdx, _} when BL < L; BL =:= L, BIdx < PIdx -> Best;
                          _ -> {L, PIdx, maps:get(PIdx, Partners)}
                      end;
                 (_, _, Best) -> Best
              end, none, Touched).

%% Forget touches too old to matter (now and then: at each stride's GC).
forget_touches(Since, #d{touched = Touched} = D) ->
    D#d{touched = maps:filter(fun(_, {T, _}) -> T > Since end, Touched)}.

%% Ask PIdx to tell us when it reaches our LVT (once per wait).
watch(PIdx, _PPid, #d{lvt = Lvt, watching = {PIdx, Lvt}} = D) -> D;
watch(PIdx, PPid, #d{lvt = Lvt} = D) ->
    send(PPid, {watch, self(), Lvt}, D),
    D#d{watching = {PIdx, Lvt}}.

on_watch(Pid, T, #d{lvt = Lvt, idx = Idx} = D) when Lvt >= T ->
    Pid ! {reached, Idx, Lvt},
    D;
on_watch(Pid, T, #d{watchers = W} = D) ->
    D#d{watchers = W#{Pid => T}}.

%% Publish the LVT; wake the bodies waiting for it.
publish_lvt(#d{sim = #sim{lvts = Lvts}, idx = Idx, lvt = Lvt, watchers = W} = D) ->
    atomics:put(Lvts, rw_timewarp:lvt_slot(Idx), Lvt),
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

advance(Lvt, Last, D) ->
    {Passed, States} = ?TIMED(D, ?ST_RED_INTEGRATE, chain(Lvt, state_at(Lvt, D), Last, D, [], [])),
    counters:add(D#d.sim#sim.stats, ?ST_COMPUTED, length(States)),
    counters:add(D#d.sim#sim.stats, ?ST_STEPS, 1),
    D1 = write_states(Lvt + D#d.dt, States, Last, D),
    %% commit every frame time this step moved past
    #d{lvt = NewLvt} = D1,
    ?TIMED(D, ?ST_RED_GVT, lists:foldl(fun({T, St, Post}, Acc) when T < NewLvt -> commit(T, St, Post, Acc);
                                         (_, Acc) -> Acc
                                      end, D1, Passed)).

timed(Stats, Stage, Fun) ->
    T0 = reductions(),
    Result = Fun(),
    counters:add(Stats, Stage, reductions() - T0),
    Result.

%% The states after T up to Last (one per substep), and the post-response
%% at each sync point passed on the way (to commit).
chain(T, _St, Last, _D, Passed, States) when T >= Last ->
    {lists:reverse(Passed), lists:reverse(States)};
chain(T, St, Last, #d{model = M, dt = Dt, frame = F, stride = S, end_t = End} = D, Passed, States) ->
    Post = {V, W, U} = rw_dynamics:respond(St, effects(T, St, D)),
    Next = rw_integrate:advance(M, St, V, W, U),
    Passed1 = case T rem F =:= 0 orelse T rem S =:= 0 orelse T =:= End of
                  true -> [{T, St, Post} | Passed];
                  false -> Passed
              end,
    chain(T + Dt, Next, Last, D, Passed1, [Next | States]).

%% Effects of every known contact at T, in canonical order of partner.
effects(T, #st{} = St, #d{model = M, sphere = S, contacts = Contacts, sim = Sim}) ->
    Bodies = case Contacts of
                 #{T := AtT} -> [{{PIdx, 0}, E} || {PIdx, E} <- maps:values(AtT)];
                 _ -> []
             end,
    Fixed = rw_dynamics:fixture_effects(M, S, St, Sim#sim.scene#scene.fixtures),
    %% (a hot path: matching both lists saves a ++ per substep, 1-2 % of Parallel 500)
    case {Bodies, Fixed} of
        {[], []} -> [];
        {[{_, E}], []} -> [E];
        {[], [{_, E}]} -> [E];
        _ -> [E || {_, E} <- lists:keysort(1, Bodies ++ Fixed)]
    end.

%% Write States (one per substep from T0 on) to the TVHT under lock;
%% stop at the first substep with contacts and send the events for them.
%% LVT becomes that substep, or Last.
write_states(T0, States, Last, #d{idx = Idx, sphere = S, model = M, sim = Sim, written = Written} = D) ->
    DispList = case M#model.ccd of
                   true -> [rw_integrate:free_displacement(M, St) || St <- States];
                   false -> undefined
               end,
    Packed = rw_states:pack(States, DispList, M#model.rotation, M#model.ccd),
    {Disps, Extents} = case DispList of
                           undefined -> {undefined, rw_states:extents(Packed)};
                           _ ->
                               DispTuple = list_to_tuple(DispList),
                               #st{p = {X, Y, Z}} = hd(States),
                               {DispTuple, extend(1, list_to_tuple(States), DispTuple, X, Y, Z, X, Y, Z)}
                       end,
    Payload = {Idx, self(), S, T0, Packed, bounds(Extents, S#sphere.radius)},
    %% hashing the states to cells and buckets is collision-checking work
    Plan = ?TIMED(D, ?ST_RED_TVHT, plan(cell_spans(T0, States, Disps, Extents, D), Sim)),
    maybe_delay(D),
    {UpTo, Hits, Ids} = probe_commit(Plan, Payload, Last, Idx),
    Where = [{B, Pid, Cells} || {B, Pid, Cells, _} <- Plan],
    MaxWindow = max(1, D#d.stride div D#d.dt),
    Window = case Hits of
                 [] -> min(MaxWindow, 2 * D#d.window);
                 _ -> min(MaxWindow, max(1, 2 * ((UpTo - T0) div D#d.dt + 1)))
             end,
    D1 = D#d{lvt = UpTo, written = [{T0, UpTo, Where, Packed} | Written], window = Window},
    publish_lvt(send_events(UpTo, Hits, Ids, D1)).

%% Probe the buckets of the plan in order under their locks, store the
%% states up to the first LVT with contacts (or Last), and unlock:
%% {UpTo, Hits by partner idx, contact ids by partner idx}.
probe_commit([{_, Pid, Cells, Spans}], Payload, Last, _Idx) ->
    {UpTo, Hs, Ids} = rw_bucket:probe_commit(Pid, self(), Cells, Payload, Spans, Last),
    {UpTo, lists:ukeysort(1, [{element(1, E), {E, C}} || {E, C} <- Hs]), Ids};
probe_commit(Plan, Payload, Last, Idx) ->
    Results = [rw_bucket:lock_probe(Pid, self(), Cells, Payload, Spans) || {_, Pid, Cells, Spans} <- Plan],
    {UpTo, Hits} = case [R || R <- Results, R =/= none] of
                       [] -> {Last, []};
                       Found ->
                           TStar = lists:min([T || {T, _} <- Found]),
                           {TStar, lists:ukeysort(1, [{element(1, E), {E, C}} || {T, Hs} <- Found, T =:= TStar,
                                                                                  {E, C} <- Hs])}
                   end,
    Ids = rw_bucket:contact_ids(UpTo, Idx, [OIdx || {OIdx, _} <- Hits]),
    [rw_bucket:commit_unlock(Pid, self(), UpTo, Ids) || {_, Pid, _, _} <- Plan],
    {UpTo, Hits, Ids}.

%% The pre-response state at substep T (GVT =< T =< LVT): in the newest
%% write that starts at or before T.
state_at(T, #d{written = Written, dt = Dt}) -> state_in(T, Written, Dt).

state_in(T, [{T0, _, _, Packed} | _], Dt) when T0 =< T -> rw_states:state(Packed, (T - T0) div Dt + 1);
state_in(T, [_ | Older], Dt) -> state_in(T, Older, Dt).

%% A box that holds the sphere at every state of a step (swept over each
%% substep with CCD), padded against rounding: the buckets skip the
%% narrowphase for two writes whose boxes are apart.
bounds({X0, Y0, Z0, X1, Y1, Z1}, R) ->
    Pad = R + 1.0e-9 * (R + lists:max([abs(X0), abs(Y0), abs(Z0), abs(X1), abs(Y1), abs(Z1)])),
    {X0 - Pad, Y0 - Pad, Z0 - Pad, X1 + Pad, Y1 + Pad, Z1 + Pad}.

%% The extents of the positions, swept over each substep (CCD: Disps holds
%% the displacements).
extend(I, Sts, _Disps, X0, Y0, Z0, X1, Y1, Z1) when I > tuple_size(Sts) -> {X0, Y0, Z0, X1, Y1, Z1};
extend(I, Sts, Disps, X0, Y0, Z0, X1, Y1, Z1) ->
    #st{p = {X, Y, Z}} = element(I, Sts),
    {DX, DY, DZ} = element(I, Disps),
    {Xa, Ya, Za} = {min(X, X + DX), min(Y, Y + DY), min(Z, Z + DZ)},
    {Xb, Yb, Zb} = {max(X, X + DX), max(Y, Y + DY), max(Z, Z + DZ)},
    extend(I + 1, Sts, Disps, min(X0, Xa), min(Y0, Ya), min(Z0, Za), max(X1, Xb), max(Y1, Yb), max(Z1, Zb)).

%% For each cell touched during the step, the first and last substep at
%% which the body's box (swept with CCD) touches it. Boxes seldom change
%% between substeps, so cells are enumerated only when they do, and a box
%% is hashed again only when it leaves the region that keeps its cells.
cell_spans(T0, [St0 | Rest], Disps, {X0, Y0, Z0, X1, Y1, Z1},
           #d{sim = #sim{scene = #scene{cell_size = C}}, sphere = #sphere{radius = R}, dt = Dt} = D) ->
    Box = rw_hash:box(aabb(St0, disp_at(Disps, 1), D), C),
    Region = rw_hash:region(Box, C),
    %% Without CCD a state's box is its position +- R, and rounding is
    %% monotonic: if the boxes at the extreme positions keep the first
    %% state's cells, every state's box does, and the step is one run.
    case Disps =:= undefined andalso
        rw_hash:in_region(rw_shape:sphere_aabb({X0, Y0, Z0}, R), Region) andalso
        rw_hash:in_region(rw_shape:sphere_aabb({X1, Y1, Z1}, R), Region) of
        true -> add_run(Box, T0, T0 + length(Rest) * Dt, #{});
        false -> spans(Rest, 2, T0 + Dt, Disps, Box, Region, T0, T0, D, #{})
    end.

%% State I of the step (at substep T) and the rest.
spans([], _I, _T, _Disps, Box, _Region, Ta, Tb, _D, Acc) ->
    add_run(Box, Ta, Tb, Acc);
spans([St | Rest], I, T, Disps, Box, Region, Ta, Tb,
      #d{sim = #sim{scene = #scene{cell_size = C}}, dt = Dt} = D, Acc) ->
    AABB = aabb(St, disp_at(Disps, I), D),
    case rw_hash:in_region(AABB, Region) of
        true -> spans(Rest, I + 1, T + Dt, Disps, Box, Region, Ta, T, D, Acc);
        false ->
            case rw_hash:box(AABB, C) of
                Box -> spans(Rest, I + 1, T + Dt, Disps, Box, Region, Ta, T, D, Acc);
                New -> spans(Rest, I + 1, T + Dt, Disps, New, rw_hash:region(New, C), T, T, D,
                             add_run(Box, Ta, Tb, Acc))
            end
    end.

add_run(Box, Ta, Tb, Acc) ->
    lists:foldl(fun(C, A) -> case A of
                                 #{C := {First, _}} -> A#{C => {First, Tb}};
                                 _ -> A#{C => {Ta, Tb}}
                             end
                end, Acc, rw_hash:box_cells(Box)).

disp_at(undefined, _) -> undefined;
disp_at(Disps, I) -> element(I, Disps).

aabb(#st{p = P}, undefined, #d{sphere = #sphere{radius = R}}) -> rw_shape:sphere_aabb(P, R);
aabb(#st{p = P}, Disp, #d{sphere = #sphere{radius = R}}) -> rw_shape:swept_aabb(P, Disp, R).

%% Group cell spans by bucket, in bucket order (the lock order):
%% [{BucketIndex, Pid, Cells, [{Cell, Ta, Tb}]}].
plan(Spans, #sim{buckets = Buckets}) ->
    NB = tuple_size(Buckets),
    ByBucket = maps:fold(fun(Cell, {Ta, Tb}, Acc) ->
                                 B = rw_hash:bucket(Cell, NB),
                                 maps:update_with(B, fun(L) -> [{Cell, Ta, Tb} | L] end, [{Cell, Ta, Tb}], Acc)
                         end, #{}, Spans),
    [{B, element(B + 1, Buckets), lists:sort([C || {C, _, _} <- Ss]), Ss}
     || {B, Ss} <- lists:sort(maps:to_list(ByBucket))].

send_events(_T, [], _Ids, D) -> D;
send_events(T, Hits, Ids, #d{idx = Idx, sphere = S, model = M, contacts = Contacts} = D) ->
    %% the pair sees both spheres' velocities after their fixture contacts
    St = seen_by_pairs(S, state_at(T, D), D),
    {Mine, Pend} = lists:foldl(
                     fun({OIdx, {{_, OPid, OS, OSt0, _}, Contact}}, {Acc, P}) ->
                             OSt = seen_by_pairs(OS, OSt0, D),
                             {Own, Theirs} = case Idx < OIdx of
                                                 true -> rw_response:pair(M, S, St, OS, OSt, Contact);
                                                 false -> swap(rw_response:pair(M, OS, OSt, S, St, Contact))
                                             end,
                             Cid = maps:get(OIdx, Ids),
                             send(OPid, {event, Cid, T, Idx, self(), Theirs}, D),
                             {Acc#{Cid => {OIdx, Own}}, P#{Cid => true}}
                     end, {maps:get(T, Contacts, #{}), D#d.pend_ev}, Hits),
    counters:add(D#d.sim#sim.stats, ?ST_EVENTS, length(Hits)),
    Partners = maps:merge(D#d.partners, maps:from_list([{OIdx, OPid} || {OIdx, {{_, OPid, _, _, _}, _}} <- Hits])),
    Touched = lists:foldl(fun({OIdx, _}, Acc) -> touch(OIdx, T, Acc) end, D#d.touched, Hits),
    D#d{contacts = Contacts#{T => Mine}, pend_ev = Pend, partners = Partners, touched = Touched}.

seen_by_pairs(S, St, #d{model = M, sim = #sim{scene = #scene{fixtures = Fixtures}}}) ->
    rw_dynamics:after_fixtures(St, rw_dynamics:fixture_effects(M, S, St, Fixtures)).

touch(PIdx, T, Touched) ->
    case Touched of
        #{PIdx := {Last, _}} when Last >= T -> Touched;
        #{PIdx := {Last, _}} -> Touched#{PIdx := {T, Last}};
        _ -> Touched#{PIdx => {T, none}}
    end.

swap({A, B}) -> {B, A}.

%%% Events and antievents

on_event(Cid, T, FromIdx, From, Effect, #d{ghosts = Ghosts, lvt = Lvt, contacts = Contacts} = D) ->
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
            D1 = D#d{contacts = Contacts#{T => (maps:get(T, Contacts, #{}))#{Cid => {FromIdx, Effect}}},
                     partners = (D#d.partners)#{FromIdx => From}, touched = touch(FromIdx, T, D#d.touched)},
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

undo(R, #d{idx = Idx, lvt = Lvt, dt = Dt, contacts = Contacts, sim = Sim, written = Written} = D) ->
    %% every bucket holding a state after R, with the cells it holds them in
    Where = lists:foldl(fun({B, Pid, Cells}, Acc) ->
                                maps:update_with({B, Pid}, fun(Cs) -> Cells ++ Cs end, Cells, Acc)
                        end, #{}, [X || {_, UpTo, Ws, _} <- Written, UpTo > R, X <- Ws]),
    maybe_delay(D),
    Plan = lists:sort(maps:to_list(Where)),
    %% (the buckets count their own work as TVHT; waiting is not work)
    Lost = ?TIMED(D, ?ST_RED_ROLLBACK_CALLS, lists:append([rw_bucket:lock_delete(Pid, self(), lists:usort(Cells), Idx, R)
                                                          || {{_, Pid}, Cells} <- Plan])),
    [rw_bucket:unlock(Pid, self()) || {{_, Pid}, _} <- Plan],
    Written1 = [{T0, min(UpTo, R), Ws, P} || {T0, UpTo, Ws, P} <- Written, T0 =< R],
    %% the writes hold a state at every substep up to LVT
    counters:add(Sim#sim.stats, ?ST_ROLLED_BACK, (Lvt - R) div Dt),
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

%% A body that cannot step until GVT advances asks rw_gvt to wake it at
%% the earliest GVT at which it might (step/3): when LVT_ub is min_step/1
%% past its LVT, reaches the end, or when no sync point lies between GVT and
%% its LVT any more. Early is harmless (it asks again), late would stall.
wake_me(#d{lvt = Lvt, end_t = End} = D) when Lvt >= End -> D;
wake_me(#d{lvt = Lvt, gvt = G, stride = S, frame = F, end_t = End, wake_at = Asked} = D) ->
    MinStep = min_step(D),
    At = max(G + 1, lists:min([Lvt + MinStep - S, End - S, max(Lvt div F * F, Lvt div S * S)])),
    case Asked of
        _ when is_integer(Asked), Asked =< At -> D;   % already asked for as early
        _ -> ok = rw_gvt:wake_at(D#d.sim#sim.gvt, self(), At), D#d{wake_at = At}
    end.

%% The shortest step a body takes once it has passed the next sync point:
%% three quarters of a stride. A write costs about the same however many
%% substeps it holds; half a stride made Parallel 500 write 36 substeps at a
%% time and run 10-15 % slower, a whole stride (GVT must reach the body's
%% LVT first) made bodies in contact wait.
min_step(#d{stride = S, dt = Dt}) -> max(Dt, (S * 3 div 4) div Dt * Dt).

%% The first sync point after GVT: GVT cannot advance before every body
%% has reached it.
next_sync(#d{gvt = G, frame = F, stride = S, end_t = End}) -> rw_gvt:sync_after(G, F, S, End).

%% Bodies commit at every frame time and every multiple of the stride, so
%% that GVT can always advance far enough for LVT_ub to reach the next one.
is_sync(T, #d{frame = F, stride = S, end_t = End}) -> T rem F =:= 0 orelse T rem S =:= 0 orelse T =:= End.

commit(T, #st{p = P, q = Q}, {V, W, _U}, #d{sim = Sim, idx = Idx, sphere = #sphere{id = Id}} = D) ->
    case T > D#d.gvt andalso is_sync(T, D) andalso not lists:member(T, D#d.committed) of
        true ->
            ets:insert(Sim#sim.records, {{T, Idx}, {Id, P, V, Q, W}}),
            _ = case ets:update_counter(Sim#sim.counts, T, 1, {T, 0}) of
                    N when N =:= Sim#sim.n -> Sim#sim.gvt ! {complete, T};
                    _ -> ok
                end,
            D#d{committed = [T | D#d.committed]};
        false ->
            D
    end.

%% A body waiting at LVT_ub (or at the end time) commits its LVT once
%% nothing is awaited there; a later event at LVT withdraws it again.
commit_lvt(#d{lvt = Lvt} = D) ->
    St = state_at(Lvt, D),
    commit(Lvt, St, rw_dynamics:respond(St, effects(Lvt, St, D)), D).

%% Take back every commit at or after T.
withdraw(T, #d{committed = Committed, sim = Sim, idx = Idx} = D) ->
    {Gone, Kept} = lists:partition(fun(C) -> C >= T end, Committed),
    [begin
         ets:update_counter(Sim#sim.counts, C, -1),
         ets:delete(Sim#sim.records, {C, Idx})
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
