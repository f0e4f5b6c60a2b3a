%% The process of one dynamic body of a Time Warp simulation: a gen_statem
%% whose states are its entity's phases (rw_entity, the pure protocol
%% machine that decides everything). It routes messages into the machine
%% and carries out the effects it returns, in order: sends, the TVHT write
%% and delete (rw_tvht, under bucket locks), commits (rw_commits), the LVT
%% it publishes, counters, and the wake-up it asks of the GVT process.
%%
%% A step is due while the entity is in step and not idle: an event
%% timeout of 0, which runs before any message not yet received, so
%% messages already in the mailbox are taken in first (drain/2): the
%% events behind a partner's published LVT are there by then.
-module(rw_body).
-behaviour(gen_statem).
-include("rigidwarp.hrl").
-export([start_link/3, describe/2]).
-export([callback_mode/0, init/1, ready/3, step/3, resolve/3, rollback/3, member/3, gather/3]).

-record(data, {
    sim :: #sim{},
    entity :: rw_entity:entity(),
    plans = none :: rw_tvht_plan:cache(),       % this entity's last TVHT plan, for its next write
    delay = 0 :: non_neg_integer()              % test hook: max pause (ms) before TVHT work and sends
}).
-opaque data() :: #data{}.
-export_type([data/0]).

%% A body's heap never shrinks below this many words (138 KiB): a step
%% allocates some 130 words per substep and keeps little, so a heap sized
%% to what survived the last collection would collect every few dozen
%% substeps. A larger heap saves no more collections, and a few hundred
%% KiB per body is more than the cores' caches hold.
-define(BODY_HEAP, 17711).
%% ... but all bodies' minimum heaps together at most this many words
%% (512 MiB): 3790 bodies and more get smaller ones, 3355 words each at
%% 20,000. A quarter of that (838 words) has them collect every few
%% substeps, and 20,000 spheres run some 8 % slower.
-define(BODIES_HEAP, 16#4000000).
%% A group's leader keeps every member's states of the substep being
%% stepped, the island's neighbour lists and the sync points passed: tens
%% of words per member that a heap sized for one body copies at almost
%% every substep. Its heap never shrinks below this many words per member
%% (a pile of 300 steps half as fast again), up to 16 MiB.
-define(MEMBER_HEAP, 4000).
-define(GROUP_HEAP, (1 bsl 21)).

%% Every collection of a body sweeps its whole heap (no old generation):
%% what survives one is mostly a step in progress, soon garbage, which a
%% generational heap promotes and later collects in a major collection of
%% both generations. A group's heap and old heap together pass 128k words,
%% and the runtime hands such a collection to a dirty scheduler: a
%% thousand hand-overs a second in Cylinders 200, whose spinning threads
%% take CPU from the two normal schedulers.
-spec start_link(#sim{}, #sphere{}, #st{}) -> gen_statem:start_ret().
start_link(#sim{n = N} = Sim, Sphere, St0) ->
    Heap = body_heap(N),
    gen_statem:start_link(?MODULE, {Sim, Sphere, St0}, [{spawn_opt, [{min_heap_size, Heap}, {fullsweep_after, 0}]}]).

body_heap(N) -> max(233, min(?BODY_HEAP, ?BODIES_HEAP div N)).

%% For the watchdog (rw_watchdog), from the state sys:get_state/2 returns:
%% the LVT and one line on the phase and whom it waits on.
-spec describe(data(), non_neg_integer()) -> {non_neg_integer(), iolist()}.
describe(#data{entity = E}, Unread) -> {rw_entity:lvt(E), rw_entity:describe(E, Unread)}.

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> [state_functions, state_enter].

-spec init({#sim{}, #sphere{}, #st{}}) -> gen_statem:init_result(ready).
init({#sim{scene = Scene, sync = Cal, owners = Owners, delay = Delay} = Sim, #sphere{idx = Idx} = Sphere, St0}) ->
    ets:insert(Owners, {Idx, self()}),
    ok = rw_trace:init(Sim#sim.trace),
    ok = rw_native:use(Sim#sim.native),
    MaxMs = case Delay of
                {Seed, Ms} -> _ = rand:seed(exsss, Seed + Idx), Ms;
                none -> 0
            end,
    {ok, ready, #data{sim = Sim, entity = rw_entity:new(self(), Scene, Cal, Sphere, St0), delay = MaxMs}}.

%%% States: the entity's phases

%% Before the simulation starts: every body exists, none has written yet.
-spec ready(gen_statem:event_type(), term(), data()) -> gen_statem:state_enter_result(ready) |
          gen_statem:event_handler_result(rw_entity:phase()).
ready(enter, _, _D) -> keep_state_and_data;
ready(info, go, D) -> run(start, D);
ready(_Type, _Msg, _D) -> {keep_state_and_data, [postpone]}.

-spec step(gen_statem:event_type(), term(), data()) -> gen_statem:state_enter_result(step) |
          gen_statem:event_handler_result(rw_entity:phase()).
step(enter, _, _D) -> keep_state_and_data;
step(timeout, step, D) -> step_now(D);
step(Type, Msg, D) -> message(Type, Msg, D).

-spec resolve(gen_statem:event_type(), term(), data()) -> gen_statem:state_enter_result(resolve) |
          gen_statem:event_handler_result(rw_entity:phase()).
resolve(enter, _, _D) -> keep_state_and_data;
resolve(Type, Msg, D) -> message(Type, Msg, D).

-spec rollback(gen_statem:event_type(), term(), data()) -> gen_statem:state_enter_result(rollback) |
          gen_statem:event_handler_result(rw_entity:phase()).
rollback(enter, _, _D) -> keep_state_and_data;
rollback(Type, Msg, D) -> message(Type, Msg, D).

-spec member(gen_statem:event_type(), term(), data()) -> gen_statem:state_enter_result(member) |
          gen_statem:event_handler_result(rw_entity:phase()).
member(enter, _, #data{sim = #sim{n = N}}) ->
    %% (a leader that hands over gives back its group's heap)
    _ = process_flag(min_heap_size, body_heap(N)),
    true = erlang:garbage_collect(),
    keep_state_and_data;
member(Type, Msg, D) -> message(Type, Msg, D).

-spec gather(gen_statem:event_type(), term(), data()) -> gen_statem:state_enter_result(gather) |
          gen_statem:event_handler_result(rw_entity:phase()).
gather(enter, _, _D) -> keep_state_and_data;
gather(Type, Msg, D) -> message(Type, Msg, D).

%% Every message of the protocol goes to the entity; anything else is
%% logged and dropped.
message(info, {event, _, _, _, _, _, _} = Msg, D) -> run(Msg, D);
message(info, {antievent, _, _, _} = Msg, D) -> run(Msg, D);
message(info, {ack, _, _} = Msg, D) -> run(Msg, D);
message(info, {gvt, _} = Msg, D) -> run(Msg, D);
message(info, {watch, _, _} = Msg, D) -> run(Msg, D);
message(info, {reached, _, _} = Msg, D) -> run(Msg, D);
message(info, {regroup, _, _} = Msg, D) -> run(Msg, D);
message(info, {bundle, _, _, _, _} = Msg, D) -> run(Msg, D);
message(Type, Msg, D) -> unexpected(Type, Msg, D).

unexpected(Type, Msg, #data{entity = E}) ->
    logger:warning("rw_body ~p: unexpected ~p ~p", [rw_entity:idx(E), Type, Msg]),
    keep_state_and_data.

run(Msg, D) ->
    {Phase, D1} = task(Msg, D),
    next(Phase, D1).

%% The state that follows; in step, a step is due unless the entity waits.
next(step, #data{entity = E} = D) ->
    case rw_entity:idle(E) of
        true -> {next_state, step, D};
        false -> {next_state, step, D, [{timeout, 0, step}]}
    end;
next(Phase, D) -> {next_state, Phase, D}.

%% A step: GVT, how far past it bodies may step (rw_sim:ahead_slot/0) and
%% the LVTs of the partners that limit it are read first, then the
%% messages already here are taken in (if there were any, the step waits
%% for the next turn), then it steps.
step_now(#data{sim = #sim{gvt_now = GvtNow, lvts = Lvts}, entity = E} = D) ->
    Gvt = atomics:get(GvtNow, 1),
    Ahead = atomics:get(GvtNow, rw_sim:ahead_slot()),
    Partners = [{P, atomics:get(Lvts, rw_sim:lvt_slot(P))} || P <- rw_entity:partners(E)],
    case drain(D, none) of
        none -> run({step, Gvt, Ahead, Partners}, D);
        {Phase, D1} -> next(Phase, D1)
    end.

drain(D, Last) ->
    receive
        {event, _, _, _, _, _, _} = Msg -> drain_more(Msg, D);
        {antievent, _, _, _} = Msg -> drain_more(Msg, D);
        {ack, _, _} = Msg -> drain_more(Msg, D);
        {gvt, _} = Msg -> drain_more(Msg, D);
        {watch, _, _} = Msg -> drain_more(Msg, D);
        {reached, _, _} = Msg -> drain_more(Msg, D);
        {regroup, _, _} = Msg -> drain_more(Msg, D)
    after 0 -> Last
    end.

drain_more(Msg, D) ->
    {Phase, D1} = task(Msg, D),
    drain(D1, {Phase, D1}).

%% Msg handled, as one task when the simulation is traced (rw_trace): a
%% step is begun by the process itself.
task(Msg, #data{sim = #sim{trace = undefined}} = D) -> feed(Msg, D);
task(Msg, D) -> rw_trace:task(body, case Msg of {step, _, _, _} -> none; _ -> Msg end, fun() -> feed(Msg, D) end).

%% The entity handles Msg; its effects are carried out, and a call's answer
%% goes back to it.
feed(Msg, #data{entity = E, sim = Sim} = D) ->
    {Phase, E1, Effects} = case Sim of
                               #sim{profile = false} -> rw_entity:handle(Msg, E);
                               #sim{stats = Stats} -> profiled_handle(Stats, stage(Msg), Msg, E)
                           end,
    perform(Effects, Phase, D#data{entity = E1}).

profiled_handle(_Stats, none, Msg, E) -> rw_entity:handle(Msg, E);
profiled_handle(Stats, Stage, Msg, E) -> rw_stats:timed(Stats, Stage, fun() -> rw_entity:handle(Msg, E) end).

stage({step, _, _, _}) -> integrate_reductions;
stage({gvt, _}) -> gvt_reductions;
stage({reply, {deleted, _}}) -> rollback_reductions;
stage(_) -> none.

perform([], Phase, D) ->
    {Phase, D};
perform([{tvht_write, T0, Spheres, Steps, Last}], _Phase, #data{sim = Sim, plans = Cache} = D) ->
    #sim{buckets = Buckets, placement = Place, scene = #scene{model = M, cell_size = Cell, substep = Dt}} = Sim,
    %% hashing the states to cells and buckets is collision-checking work
    {Write, Plan, Cache1} = profiled(Sim, tvht_reductions, rw_tvht_plan, write,
                                     [self(), T0, Spheres, Steps, M, {Cell, Dt}, Place, Cache]),
    maybe_delay(D),
    {UpTo, Hits, Ids, Where} = rw_tvht:write(Buckets, Write, Plan, Last),
    feed({reply, {written, UpTo, Hits, Ids, Where}}, D#data{plans = Cache1});
perform([{tvht_delete, Where, Idxs, R}], _Phase, #data{sim = #sim{buckets = Buckets}} = D) ->
    maybe_delay(D),
    feed({reply, {deleted, rw_tvht:delete(Buckets, self(), Where, Idxs, R)}}, D);
perform([Effect | Rest], Phase, D) ->
    ok = effect(Effect, D),
    perform(Rest, Phase, D).

effect({send, To, Msg}, D) ->
    maybe_delay(D),
    rw_trace:send(To, Msg);
effect({watch, PIdx, Lvt}, #data{sim = #sim{owners = Owners}} = D) ->
    [{_, Pid}] = ets:lookup(Owners, PIdx),
    maybe_delay(D),
    rw_trace:send(Pid, {watch, self(), Lvt});
effect({publish_lvt, Idxs, Lvt}, #data{sim = #sim{lvts = Lvts}}) ->
    publish(Idxs, Lvts, Lvt);
effect({commit, T, Records, Planned}, #data{sim = Sim}) ->
    ok = rw_trace:committed(T),
    profiled(Sim, gvt_reductions, rw_commits, commit, [Sim, T, Records, Planned]);
effect({keep, Records}, #data{sim = Sim}) ->
    rw_commits:keep(Sim, Records);
effect({withdraw, Times, Idxs}, #data{sim = Sim}) ->
    rw_commits:withdraw(Sim, Times, Idxs);
effect({count, Name, N}, #data{sim = #sim{stats = Stats}}) ->
    rw_stats:add(Stats, Name, N);
effect({met, A, B, T}, #data{sim = #sim{met = Met}}) ->
    true = ets:insert(Met, {{A, B}, T}),
    ok;
effect({wake_at, At}, #data{sim = #sim{gvt = Gvt}}) ->
    rw_gvt:wake_at(Gvt, self(), At);
effect({regroup_ack, S}, #data{sim = #sim{gvt = Gvt}}) ->
    rw_gvt:regroup_ack(Gvt, self(), S);
effect({own, Idxs}, #data{sim = #sim{owners = Owners, n = N}}) ->
    true = ets:insert(Owners, [{I, self()} || I <- Idxs]),
    _ = process_flag(min_heap_size, max(body_heap(N), min(?MEMBER_HEAP * length(Idxs), ?GROUP_HEAP))),
    ok.

publish([], _Lvts, _Lvt) -> ok;
publish([I | Rest], Lvts, Lvt) ->
    ok = atomics:put(Lvts, rw_sim:lvt_slot(I), Lvt),
    publish(Rest, Lvts, Lvt).

%% Mod:Fun(Args...), counted as Stage when the simulation is profiled (a
%% fun is made only then: see rw_bucket:instrumented/2).
profiled(#sim{profile = false}, _Stage, Mod, Fun, Args) -> apply(Mod, Fun, Args);
profiled(#sim{stats = Stats}, Stage, Mod, Fun, Args) -> rw_stats:timed(Stats, Stage, fun() -> apply(Mod, Fun, Args) end).

%% Test hook: a random pause before TVHT work and sends shuffles the order
%% in which bodies interleave (liveness and equality must not depend on
%% it; the sender pauses, which keeps per-pair order).
maybe_delay(#data{delay = 0}) -> ok;
maybe_delay(#data{delay = MaxMs}) ->
    case rand:uniform(MaxMs + 2) - 2 of
        -1 -> erlang:yield(), ok;
        0 -> ok;
        Ms -> timer:sleep(Ms)
    end.
