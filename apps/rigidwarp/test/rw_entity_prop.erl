%% A model of a whole Time Warp simulation built from the pure protocol
%% machine (rw_entity), with no processes: several entities exchanging
%% events, antievents and acknowledgements over a network that delivers
%% every message eventually, in order per sender and receiver (as Erlang
%% does) but in any order otherwise; a TVHT of one to four buckets (rw_cells,
%% written and deleted atomically, as their locks make it); the commit counter and GVT
%% (as rw_gvt: GVT passes a sync point once every body has committed it,
%% writes frames, wakes whom asked, plans regroups with rw_regroup); and
%% the processes' shared state (published LVTs, owners, met pairs).
%%
%% proper_statem drives it: each command delivers the oldest message of one
%% channel, lets one entity with a step due take it, or takes a burst of
%% such actions picked by a seeded generator, in random order, so
%% rollbacks, antievents and regroups meet in orders a real run reaches
%% only by chance. After the random prefix the run is completed in a fixed
%% fair order. The checks are the paper's lemmas and the engine's promise:
%%   - no deadlock: until GVT reaches the end, some message can be
%%     delivered or some entity can step;
%%   - a committed state is never rolled back: no rollback to before GVT,
%%     no commit at or before GVT withdrawn;
%%   - every event is acknowledged at most once, and at the end each was
%%     acknowledged or cancelled by an antievent; every antievent is
%%     acknowledged exactly once;
%%   - at the end, the frames GVT committed (the sync points among them:
%%     the calendar may make only every second or third frame one) equal the sequential
%%     reference's, bit for bit;
%%   - the machine never raises (a protocol error).
-module(rw_entity_prop).
-include_lib("proper/include/proper.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").

-export([prop_protocol/0]).
-export([initial_state/0, command/1, precondition/2, postcondition/3, next_state/3]).
-export([deliver/1, step/1, burst/2, quiescent/0]).
%% for the suite and a shell
-export([scene/0, model/2, complete/1, final_errors/2]).

%% PropEr 1.2 itself crashes (erlang:get_stacktrace/0 is gone) when a
%% property raises, so a property body runs under ?SAFE, which turns an
%% exception into a failure that prints it.
-define(SAFE(Body),
        try Body
        catch Class:Reason:Stack ->
                ?WHENFAIL(io:format("raised ~p:~p~n~p~n", [Class, Reason, Stack]), false)
        end).

-record(gvtp, {
    g = -1 :: integer(),                     % last sync point passed
    complete = #{} :: #{non_neg_integer() => true},
    waiting = [] :: [{integer(), [term()]}],
    groups :: rw_regroup:groups(),
    unready = #{} :: #{non_neg_integer() => [term()]},
    frames = [] :: [rw_reference:frame()]    % newest first
}).

-record(m, {
    scene :: #scene{},
    ahead = stride :: ahead_mode(),           % how far past GVT entities may step (ahead/1)
    cal :: rw_sync:calendar(),
    n :: pos_integer(),
    ents = #{} :: #{non_neg_integer() => rw_entity:entity()},
    phase = #{} :: #{non_neg_integer() => rw_entity:phase()},
    due = #{} :: #{non_neg_integer() => boolean()},
    %% messages on their way, per {From, To}, oldest first, each with a
    %% sequence number
    chans = #{} :: #{{term(), term()} => [{non_neg_integer(), term()}]},
    seq = 0 :: non_neg_integer(),
    owners = #{} :: #{non_neg_integer() => non_neg_integer()},
    lvts = #{} :: #{non_neg_integer() => non_neg_integer()},
    gvt = -1 :: integer(),                   % as published
    buckets :: tuple(),                      % the TVHT: rw_cells, bucket index 0 at element 1
    uniq = 0 :: non_neg_integer(),
    counts = #{} :: #{non_neg_integer() => integer()},
    records = #{} :: #{{non_neg_integer(), non_neg_integer()} => rw_reference:body_frame()},
    %% the records an entity said the regroup plan may read (with sparse
    %% records, the only ones kept besides checkpoints and the end)
    planned = #{} :: #{{non_neg_integer(), non_neg_integer()} => true},
    met = #{} :: #{{non_neg_integer(), non_neg_integer()} => non_neg_integer()},
    gp :: #gvtp{},
    %% the checks' books
    events = #{} :: #{rw_entity:cid() => {term(), term()}},
    event_acks = #{} :: #{rw_entity:cid() => pos_integer()},
    antievents = #{} :: #{{rw_entity:cid(), term()} => term()},
    anti_acks = #{} :: #{{rw_entity:cid(), term()} => pos_integer()},
    actions = 0 :: non_neg_integer(),        % messages delivered and steps taken
    stepped = #{} :: #{non_neg_integer() => non_neg_integer()},   % when each entity last stepped (actions)
    rollbacks = 0 :: non_neg_integer(),
    regroups = 0 :: non_neg_integer(),
    errors = [] :: [term()]
}).

%%% The property

-spec prop_protocol() -> proper:test().
prop_protocol() ->
    ?FORALL({Scene, Groups}, {scene(), {groups(), oneof([1, 2, 4]), sync_every(), ahead_mode()}},
            begin
                %% (the model is built from this small term when the first
                %% command needs it, so that a counterexample prints short)
                M0 = {unbuilt, Scene, Groups},
                Ref = reference(Scene),
                ?FORALL(Cmds, commands(?MODULE, M0),
                        ?SAFE(begin
                            {History, M1, Result} = run_commands(?MODULE, Cmds),
                            M = case M1 of #m{} -> M1; _ -> built(M1) end,
                            Final = complete(M),
                            Errors = final_errors(Final, Ref),
                            ?WHENFAIL(io:format("scene: ~p~ngroups: ~p~nresult: ~p~nerrors: ~p~nhistory length ~b~n",
                                                [scene_summary(Scene), Groups, Result, Errors, length(History)]),
                                      aggregate(command_names(Cmds),
                                                collect({outcome(Final), random_share(M, Final)},
                                                        Result =:= ok andalso Errors =:= [])))
                        end))
            end).

%% How much of the run the random commands did (the rest is the fair
%% completion's).
random_share(#m{actions = A}, #m{actions = A}) -> random_all;
random_share(#m{actions = A}, #m{actions = All}) when 2 * A >= All -> random_half_or_more;
random_share(_, _) -> random_less_than_half.

outcome(#m{antievents = A, rollbacks = R, regroups = G}) ->
    {case map_size(A) of 0 -> no_antievent; _ -> antievents end,
     case R of 0 -> no_rollback; _ -> rollbacks end,
     case G of 0 -> no_regroup; _ -> regroups end}.

scene_summary(#scene{spheres = Spheres, initial = Initial, duration = D, substep = Dt, stride = St, frame = F,
                     model = #model{gravity = G, rotation = R, friction = Mu, ccd = Ccd}, start = T0}) ->
    #{start => T0, duration => D, substep => Dt, stride => St, frame => F, gravity => G, rotation => R, friction => Mu, ccd => Ccd,
      spheres => [{Id, Rad, P, V} || {#sphere{id = Id, radius = Rad}, #st{p = P, v = V}} <- lists:zip(Spheres, Initial)]}.

%%% Generators

%% A few spheres in a small box, fast enough to meet each other and the
%% walls many times in a few dozen substeps.
-spec scene() -> proper_types:type().
scene() ->
    ?LET({N, Seed, Speed, Gravity, Rotation, Friction, Ccd, Stride, Frame, Dur},
         {range(4, 12), range(1, 1000000), oneof([5.0, 15.0, 30.0]), boolean(), boolean(), oneof([none, 0.5]),
          boolean(), oneof([2, 4, 8]), oneof([1, 2, 4]), oneof([40, 80])},
         begin
             Model0 = #{<<"restitution">> => 0.8, <<"rotation">> => Rotation, <<"ccd">> => Ccd},
             Model1 = case Gravity of true -> Model0#{<<"gravity">> => [0.0, -9.81, 0.0]}; false -> Model0 end,
             Model = case Friction of none -> Model1; Mu -> Model1#{<<"friction">> => Mu} end,
             Map = #{<<"name">> => <<"model">>, <<"duration_ms">> => Dur, <<"substep_ms">> => 1,
                     <<"frame_ms">> => Frame, <<"stride_ms">> => Stride, <<"model">> => Model,
                     <<"bodies">> => [#{<<"id">> => <<"cage">>, <<"shape">> => <<"box">>, <<"static">> => true,
                                        <<"hollow">> => true, <<"half_extents">> => [0.35, 0.35, 0.35],
                                        <<"position">> => [0, 0, 0]}],
                     <<"generators">> => [#{<<"type">> => <<"random">>, <<"id_prefix">> => <<"s">>, <<"count">> => N,
                                            <<"seed">> => Seed, <<"min">> => [-0.35, -0.35, -0.35],
                                            <<"max">> => [0.35, 0.35, 0.35], <<"radius">> => 0.1, <<"mass">> => 1.0,
                                            <<"speed">> => Speed}]},
             {ok, Scene} = rw_scene:from_map(Map, #{}),
             resumed(Scene, Seed rem 3)

         end).

%% A third of the runs start where a run from 0 committed a frame (a run
%% resumed from a checkpoint): from the reference's checkpoint at a frame
%% time in the first half.
resumed(Scene, 0) -> Scene;
resumed(#scene{duration = End, frame = F} = Scene, K) ->
    T0 = (End div 2) div F div K * F,
    Self = self(),
    Ref = make_ref(),
    {ok, _} = rw_reference:run(Scene#scene{duration = max(T0, F)},
                               #{on_checkpoint => fun(C) -> Self ! {Ref, C} end, checkpoint_ms => 0}),
    rw_scene:from_checkpoint(Scene, lists:last(drain(Ref))).

%% Contact groups: off (one entity per body, as the paper), or groups of
%% bodies near each other planned at every regroup point, however they
%% move, so that groups form and break up all the time.
groups() -> frequency([{3, off}, {1, {eager, 2, 1}}, {1, {eager, 3, 2}}]).

%% Every how many frame times a sync point falls: every one, or (as when
%% nobody reads the frames) every second or third; frames between are
%% not committed.
sync_every() -> frequency([{2, 1}, {1, 2}, {1, 3}]).

%% How far past GVT entities may step: the stride; now and then less; or
%% always one substep, as under a memory guard that holds the run back to
%% the least (rw_memory_guard).
-type ahead_mode() :: stride | varying | least.
ahead_mode() -> frequency([{3, stride}, {1, varying}, {1, least}]).

%%% The model's start

-type unbuilt() :: {unbuilt, #scene{}, {off | {eager, pos_integer(), pos_integer()}, pos_integer(), pos_integer(),
                                          ahead_mode()}}.

built({unbuilt, Scene, Groups}) -> model(Scene, Groups).

-spec model(#scene{}, {off | {eager, pos_integer(), pos_integer()}, pos_integer(), pos_integer(), ahead_mode()}) -> #m{}.
model(#scene{spheres = Spheres, initial = Initial, duration = End, frame = Frame, stride = Stride, model = Model,
             substep = Dt, start = Start} = Scene, {Groups, NBuckets, SyncEvery, AheadMode}) ->
    {Period, Max} = case Groups of
                        off -> {0, 1};
                        {eager, GMax, Every} -> {Every * Stride, GMax}
                    end,
    Cal = rw_sync:sparse(rw_sync:new(Frame, Stride, End, Period, Start), SyncEvery),
    Idxs = [I || #sphere{idx = I} <- Spheres],
    Ents = maps:from_list([{I, rw_entity:new(I, Scene, Cal, S, St)} || {#sphere{idx = I} = S, St} <- lists:zip(Spheres, Initial)]),
    M0 = #m{scene = Scene, cal = Cal, n = length(Spheres), ents = Ents, ahead = AheadMode,
            phase = maps:from_list([{I, ready} || I <- Idxs]), due = maps:from_list([{I, false} || I <- Idxs]),
            owners = maps:from_list([{I, I} || I <- Idxs]), lvts = maps:from_list([{I, Start} || I <- Idxs]),
            buckets = list_to_tuple([rw_cells:new(Model, Dt) || _ <- lists:seq(1, NBuckets)]), gp = #gvtp{groups = rw_regroup:new(Idxs, Max, eager)}},
    lists:foldl(fun(I, M) -> enqueue(sup, I, start, M) end, M0, Idxs).

%%% proper_statem

-spec initial_state() -> #m{}.
initial_state() -> error(use_commands_2).

-spec command(#m{} | unbuilt()) -> proper_types:type().
command({unbuilt, _, _} = U) -> command(built(U));
command(#m{errors = [_ | _]}) -> {call, ?MODULE, quiescent, []};
command(M) ->
    Chans = deliverable(M),
    Due = [I || {I, true} <- maps:to_list(M#m.due)],
    case {Chans, Due} of
        {[], []} -> {call, ?MODULE, quiescent, []};
        _ -> frequency([{3, {call, ?MODULE, deliver, [elements(Chans)]}} || Chans =/= []]
                       ++ [{1, {call, ?MODULE, step, [elements(Due)]}} || Due =/= []]
                       ++ [{4, {call, ?MODULE, burst, [range(0, 1 bsl 30), range(1, 150)]}}])
    end.

-spec precondition(#m{} | unbuilt(), tuple()) -> boolean().
precondition({unbuilt, _, _} = U, Call) -> precondition(built(U), Call);
precondition(M, {call, _, deliver, [Chan]}) -> lists:member(Chan, deliverable(M));
precondition(M, {call, _, step, [I]}) -> maps:get(I, M#m.due, false);
precondition(M, {call, _, burst, [_, _]}) -> enabled(M) =/= [];
precondition(M, {call, _, quiescent, []}) ->
    %% (after an error, the command that reports it)
    M#m.errors =/= [] orelse (deliverable(M) =:= [] andalso not lists:member(true, maps:values(M#m.due))).

%% Every transition's checks hold; and where nothing can happen, the
%% simulation has reached its end (no deadlock).
-spec postcondition(#m{} | unbuilt(), tuple(), term()) -> boolean().
postcondition({unbuilt, _, _} = U, Call, Res) -> postcondition(built(U), Call, Res);
postcondition(M, {call, _, quiescent, []}, _) -> M#m.errors =:= [] andalso done(M);
postcondition(M, Call, _) -> (next_state(M, ok, Call))#m.errors =:= [].

-spec next_state(#m{} | unbuilt(), term(), tuple()) -> #m{}.
next_state({unbuilt, _, _} = U, Res, Call) -> next_state(built(U), Res, Call);
next_state(M, _Res, {call, _, deliver, [Chan]}) -> guarded(fun() -> do_deliver(Chan, M) end, M);
next_state(M, _Res, {call, _, step, [I]}) -> guarded(fun() -> do_step(I, M) end, M);
next_state(M, _Res, {call, _, burst, [Seed, Len]}) -> do_burst(Seed, Len, M);
next_state(M, _Res, {call, _, quiescent, []}) -> M.

%% The system under test is the model itself (pure): the commands do
%% nothing but name the transition.
-spec deliver(term()) -> ok.
deliver(_Chan) -> ok.
-spec step(non_neg_integer()) -> ok.
step(_I) -> ok.
-spec burst(non_neg_integer(), pos_integer()) -> ok.
burst(_Seed, _Len) -> ok.
-spec quiescent() -> ok.
quiescent() -> ok.

%% Len actions, each picked among those enabled by a generator seeded
%% with Seed: long random schedules in few commands (a command costs
%% PropEr far more than the model's transition does).
do_burst(_Seed, 0, M) -> M;
do_burst(_Seed, _Len, #m{errors = [_ | _]} = M) -> M;
do_burst(Seed, Len, M) ->
    case enabled(M) of
        [] -> M;
        Actions ->
            Next = (Seed * 1103515245 + 12345) band 16#3fffffff,
            M1 = case lists:nth(Next rem length(Actions) + 1, Actions) of
                     {deliver, Chan} -> guarded(fun() -> do_deliver(Chan, M) end, M);
                     {step, I} -> guarded(fun() -> do_step(I, M) end, M)
                 end,
            do_burst(Next, Len - 1, M1)
    end.

enabled(M) ->
    [{deliver, Chan} || Chan <- lists:sort(deliverable(M))] ++ [{step, I} || {I, true} <- lists:sort(maps:to_list(M#m.due))].

guarded(Fun, M) ->
    try Fun()
    catch Class:Reason:Stack -> M#m{errors = [{Class, Reason, lists:sublist(Stack, 4)} | M#m.errors]}
    end.

done(#m{gp = #gvtp{g = G}, gvt = Published, cal = Cal}) ->
    End = rw_sync:end_t(Cal),
    G =:= End andalso Published =:= End.

%%% Completing a run: the oldest message first, else the entity with a
%%% step due that stepped least recently (a fair scheduler: an entity that
%%% watches a partner whose group is being formed asks again and again
%%% until it is), until nothing is left to do.

-spec complete(#m{}) -> #m{}.
complete(M) -> complete(M, 500000).

complete(#m{errors = [_ | _]} = M, _) -> M;
complete(M, 0) -> M#m{errors = [livelock]};
complete(M, Budget) ->
    case {oldest(M), next_due(M)} of
        {none, []} ->
            case done(M) of
                true -> M;
                false -> M#m{errors = [{deadlock, stuck(M)}]}
            end;
        {none, [I | _]} -> complete(guarded(fun() -> do_step(I, M) end, M), Budget - 1);
        {Chan, _} -> complete(guarded(fun() -> do_deliver(Chan, M) end, M), Budget - 1)
    end.

next_due(#m{due = Due, stepped = Stepped}) ->
    [I || {_, I} <- lists:sort([{maps:get(I, Stepped, -1), I} || {I, true} <- maps:to_list(Due)])].

stuck(#m{phase = Phase, ents = Ents, gp = #gvtp{g = G, unready = U}}) ->
    #{gvt => G, unready => U, entities => [{I, P, rw_entity:lvt(maps:get(I, Ents))} || {I, P} <- maps:to_list(Phase)]}.

%% What is wrong once the run is complete.
-spec final_errors(#m{}, [rw_reference:frame()]) -> [term()].
final_errors(#m{errors = [_ | _] = Errors}, _Ref) -> Errors;
final_errors(#m{gp = #gvtp{frames = Frames}, cal = Cal, scene = Scene} = M, Ref0) ->
    Got = lists:reverse(Frames),
    Synced = maps:from_list([{rw_scene:ms(Scene, T), true}
                             || T <- lists:seq(rw_sync:start(Cal), rw_sync:end_t(Cal)), rw_sync:is_frame(T, Cal),
                                rw_sync:is_sync(T, Cal)]),
    Ref = [F || {frame, Ms, _} = F <- Ref0, is_map_key(Ms, Synced)],
    [{frames_differ, rw_test_lib:first_difference(Ref, Got)} || not rw_test_lib:bitwise_equal(Ref, Got)]
        ++ [{antievent_not_acked_once, K, maps:get(K, M#m.anti_acks, 0)}
            || K <- maps:keys(M#m.antievents), maps:get(K, M#m.anti_acks, 0) =/= 1]
        ++ [{event_neither_acked_nor_cancelled, Cid}
            || Cid <- maps:keys(M#m.events), not maps:is_key(Cid, M#m.event_acks), not cancelled(Cid, M)].

cancelled(Cid, #m{antievents = A}) -> lists:any(fun({C, _}) -> C =:= Cid end, maps:keys(A)).

reference(Scene) ->
    Self = self(),
    Ref = make_ref(),
    {ok, _} = rw_reference:run(Scene, #{on_frame => fun(F) -> Self ! {Ref, F} end}),
    drain(Ref).

drain(Ref) -> receive {Ref, F} -> [F | drain(Ref)] after 0 -> [] end.

%%% The network

enqueue(From, To, Msg, #m{chans = C, seq = Seq} = M) ->
    M#m{chans = maps:update_with({From, To}, fun(Q) -> Q ++ [{Seq, Msg}] end, [{Seq, Msg}], C), seq = Seq + 1}.

%% Channels whose oldest message can be taken now: an entity that has not
%% started takes only its start (the process postpones the rest).
deliverable(#m{chans = C, phase = Phase}) ->
    [Chan || {{_, To} = Chan, [{_, Msg} | _]} <- maps:to_list(C),
             To =:= gvt orelse maps:get(To, Phase) =/= ready orelse Msg =:= start].

oldest(M) ->
    case [{Seq, Chan} || Chan <- deliverable(M), [{Seq, _} | _] <- [maps:get(Chan, M#m.chans)]] of
        [] -> none;
        Seqs -> element(2, lists:min(Seqs))
    end.

do_deliver({From, To} = Chan, #m{chans = C, actions = A} = M0) ->
    [{_, Msg} | Rest] = maps:get(Chan, C),
    M = M0#m{actions = A + 1, chans = case Rest of [] -> maps:remove(Chan, C); _ -> C#{Chan := Rest} end},
    case To of
        gvt -> gvt(Msg, M);
        _ -> feed(To, Msg, check_ack(From, To, Msg, M))
    end.

%% An acknowledgement arrives where its event or antievent came from.
check_ack(From, To, {ack, anti, Cid}, #m{antievents = A} = M) ->
    case maps:find({Cid, To}, A) of
        {ok, From} -> M;
        _ -> fail(M, {stray_antievent_ack, Cid, From, To})
    end;
check_ack(_From, _To, _Msg, M) -> M.

do_step(I, #m{ents = Ents, gvt = Gvt, lvts = Lvts, actions = A, stepped = Stepped} = M0) ->
    M = M0#m{actions = A + 1, stepped = Stepped#{I => A}},
    Partners = [{P, maps:get(P, Lvts)} || P <- rw_entity:partners(maps:get(I, Ents))],
    feed(I, {step, Gvt, ahead(M), Partners}, M).

%% How far past GVT an entity may step (ahead_mode/0); the promises
%% checked hold whatever it is.
ahead(#m{ahead = stride, scene = #scene{stride = S}}) -> S;
ahead(#m{ahead = least, scene = #scene{substep = Dt}}) -> Dt;
ahead(#m{ahead = varying, scene = #scene{stride = S, substep = Dt}, actions = A}) ->
    case A rem 5 of
        0 -> Dt;
        1 -> max(Dt, S div 2 div Dt * Dt);
        _ -> S
    end.

%% Entity I handles Msg; its effects are carried out in order, and a call's
%% answer goes back to it.
feed(I, Msg, #m{ents = Ents} = M) ->
    {Phase, E, Effects} = rw_entity:handle(Msg, maps:get(I, Ents)),
    effects(I, Effects, M#m{ents = Ents#{I := E}, phase = (M#m.phase)#{I := Phase},
                            due = (M#m.due)#{I := Phase =:= step andalso not rw_entity:idle(E)}}).

effects(_I, [], M) -> M;
effects(I, [{tvht_write, T0, Spheres, Steps, Last}], #m{scene = Scene, buckets = Buckets0, uniq = U} = M) ->
    %% as rw_tvht:write/4 under the buckets' locks: probe every bucket of
    %% the plan, then store the write in each up to the first contacts
    #scene{model = Model, cell_size = Cell, substep = Dt} = Scene,
    {Write, Plan} = rw_tvht_plan:write(I, T0, Spheres, Steps, Model, {Cell, Dt}, tuple_size(Buckets0)),
    Probes = [{B, CellList, Spans, rw_tvht_plan:for_bucket(Write, Spans)} || {B, CellList, Spans} <- Plan],
    Results = [rw_cells:probe(W, Spans, element(B + 1, Buckets0)) || {B, _, Spans, W} <- Probes],
    {UpTo, Hits} = rw_tvht_plan:first_contacts(Results, Last),
    Pairs = [{Idx, OIdx} || {Idx, {OIdx, _, _, _, _}, _} <- Hits],
    Ids = rw_cells:contact_ids(UpTo, Pairs, lists:seq(U, U + length(Pairs) - 1)),
    Buckets = lists:foldl(fun({{B, _, Spans, W}, Result}, Acc) ->
                                  setelement(B + 1, Acc, rw_cells:store(I, W, Spans, Result, UpTo, Ids, element(B + 1, Acc)))
                          end, Buckets0, lists:zip(Probes, Results)),
    feed(I, {reply, {written, UpTo, Hits, Ids, [{B, CellList} || {B, CellList, _, _} <- Probes]}},
         M#m{buckets = Buckets, uniq = U + length(Pairs)});
effects(I, [{tvht_delete, Where, Idxs, R}], #m{buckets = Buckets0, gp = #gvtp{g = G}} = M0) ->
    M = case R >= G of
            true -> M0;
            false -> fail(M0, {rollback_before_gvt, I, R, G})
        end,
    {Lost, Buckets} = lists:foldl(fun({B, Cells}, {L, Acc}) ->
                                          {L1, C1} = rw_cells:delete(I, Idxs, R, Cells, element(B + 1, Acc)),
                                          {L ++ L1, setelement(B + 1, Acc, C1)}
                                  end, {[], Buckets0}, rw_tvht_plan:delete(Where)),
    feed(I, {reply, {deleted, Lost}}, M#m{buckets = Buckets, rollbacks = M#m.rollbacks + 1});
effects(I, [Effect | Rest], M) ->
    effects(I, Rest, effect(I, Effect, M)).

effect(I, {send, To, Msg}, M) -> enqueue(I, To, Msg, book(I, To, Msg, M));
effect(I, {watch, PIdx, Lvt}, #m{owners = Owners} = M) -> enqueue(I, maps:get(PIdx, Owners), {watch, I, Lvt}, M);
effect(_I, {publish_lvt, Idxs, Lvt}, #m{lvts = Lvts} = M) ->
    M#m{lvts = lists:foldl(fun(X, L) -> L#{X => Lvt} end, Lvts, Idxs)};
effect(I, {commit, T, Rows, Planned}, #m{records = R, counts = C, n = N, gp = #gvtp{g = G}} = M0) ->
    M = case T > G of
            true -> M0;
            false -> fail(M0, {commit_at_or_before_gvt, I, T, G})
        end,
    Count = maps:get(T, C, 0) + length(Rows),
    M1 = keep(Planned, Rows, M#m{records = lists:foldl(fun({Key, _, _} = Row, Acc) -> Acc#{Key => element(1, rw_commits:unpack(Row))} end, R, Rows), counts = C#{T => Count}}),
    case Count of
        N -> enqueue(I, gvt, {complete, T}, M1);
        _ -> M1
    end;
effect(I, {keep, Rows}, #m{records = R} = M) ->
    case [Key || {Key, _, _} <- Rows, not is_map_key(Key, R)] of
        [] -> keep(true, Rows, M);
        Uncommitted -> fail(M, {kept_uncommitted, I, Uncommitted})
    end;
effect(I, {withdraw, Times, Idxs}, #m{records = R, counts = C, gp = #gvtp{g = G}} = M) ->
    M1 = case [T || T <- Times, T =< G] of
             [] -> M;
             Committed -> fail(M, {committed_state_withdrawn, I, Committed, G})
         end,
    M1#m{counts = lists:foldl(fun(T, Acc) -> Acc#{T => maps:get(T, Acc, 0) - length(Idxs)} end, C, Times),
         records = maps:without([{T, Idx} || T <- Times, Idx <- Idxs], R),
         planned = maps:without([{T, Idx} || T <- Times, Idx <- Idxs], M1#m.planned)};
effect(_I, {count, _, _}, M) -> M;
effect(_I, {met, A, B, T}, #m{met = Met} = M) -> M#m{met = Met#{{A, B} => T}};
effect(I, {wake_at, At}, M) -> enqueue(I, gvt, {wake_at, I, At}, M);
effect(I, {regroup_ack, S}, M) -> enqueue(I, gvt, {regroup_ack, S, I}, M);
effect(I, {own, Idxs}, #m{owners = Owners} = M) -> M#m{owners = lists:foldl(fun(X, O) -> O#{X => I} end, Owners, Idxs)}.

%% The books of the acknowledgement checks.
book(I, To, {event, Cid, _, _, _, _, _}, #m{events = E} = M) ->
    case maps:is_key(Cid, E) of
        true -> fail(M, {event_sent_twice, Cid});
        false -> M#m{events = E#{Cid => {I, To}}}
    end;
book(I, _To, {ack, event, Cid}, #m{event_acks = A} = M) ->
    case maps:get(Cid, A, 0) of
        0 -> M#m{event_acks = A#{Cid => 1}};
        _ -> fail(M, {event_acked_twice, Cid, I})
    end;
book(I, To, {antievent, Cid, _, _}, #m{antievents = A} = M) ->
    case maps:is_key({Cid, I}, A) of
        true -> fail(M, {antievent_sent_twice, Cid, I});
        false -> M#m{antievents = A#{{Cid, I} => To}}
    end;
book(I, To, {ack, anti, Cid}, #m{anti_acks = A} = M) ->
    case maps:get({Cid, To}, A, 0) of
        0 -> M#m{anti_acks = A#{{Cid, To} => 1}};
        N -> fail(M#m{anti_acks = A#{{Cid, To} => N + 1}}, {antievent_acked_twice, Cid, I})
    end;
book(_I, _To, _Msg, M) -> M.

fail(#m{errors = E} = M, What) -> M#m{errors = [What | E]}.

%%% The GVT process (as rw_gvt)

gvt({complete, T}, #m{gp = Gp} = M) -> advance(M#m{gp = Gp#gvtp{complete = (Gp#gvtp.complete)#{T => true}}});
gvt({wake_at, I, At}, #m{gp = #gvtp{g = G}} = M) when At =< G -> enqueue(gvt, I, {gvt, G}, M);
gvt({wake_at, I, At}, #m{gp = #gvtp{waiting = W} = Gp} = M) -> M#m{gp = Gp#gvtp{waiting = add_waiting(At, I, W)}};
gvt({regroup_ack, S, I}, #m{gp = #gvtp{unready = U} = Gp} = M) ->
    Left = lists:delete(I, maps:get(S, U)),
    advance(M#m{gp = Gp#gvtp{unready = case Left of [] -> maps:remove(S, U); _ -> U#{S := Left} end}}).

advance(#m{gp = #gvtp{g = G0}} = M0) ->
    {Passed, #m{gp = #gvtp{g = G} = Gp} = M1} = advance_over([], M0),
    case G > G0 of
        true ->
            {Due, Later} = lists:partition(fun({At, _}) -> At =< G end, Gp#gvtp.waiting),
            M2 = M1#m{gvt = G, buckets = list_to_tuple([rw_cells:gc(G, B) || B <- tuple_to_list(M1#m.buckets)]),
                      gp = Gp#gvtp{waiting = Later}},
            M3 = lists:foldl(fun(I, Acc) -> enqueue(gvt, I, {gvt, G}, Acc) end, M2,
                             lists:append([Is || {_, Is} <- Due])),
            lists:foldl(fun finish/2, M3, lists:reverse(Passed));
        false ->
            M1
    end.

advance_over(Passed, #m{gp = #gvtp{g = G, complete = C, unready = U} = Gp, cal = Cal, n = N, counts = Counts} = M) ->
    Next = rw_sync:after_gvt(G, Cal),
    Held = map_size(U) > 0 andalso Next >= lists:min(maps:keys(U)),
    case (not Held) andalso maps:take(Next, C) of
        {true, C1} ->
            case maps:get(Next, Counts, 0) of
                N ->
                    M1 = regroup(Next, M#m{gp = Gp#gvtp{complete = C1, g = Next}}),
                    case Next =:= rw_sync:end_t(Cal) of
                        true -> {[Next | Passed], M1};
                        false -> advance_over([Next | Passed], M1)
                    end;
                _ -> {Passed, M#m{gp = Gp#gvtp{complete = C1}}}
            end;
        _ -> {Passed, M}
    end.

finish(T, #m{scene = Scene, cal = Cal, records = R, counts = C, gp = Gp} = M) ->
    case rw_sync:is_frame(T, Cal) of
        true ->
            #scene{spheres = Spheres} = Scene,
            Frame = {frame, rw_scene:ms(Scene, T), [maps:get({T, Idx}, R) || #sphere{idx = Idx} <- Spheres]},
            M#m{counts = maps:remove(T, C), gp = Gp#gvtp{frames = [Frame | Gp#gvtp.frames]}};
        false ->
            M#m{counts = maps:remove(T, C)}
    end.

%% Every member of a group has kept its record at regroup point X: the
%% plan reads them also with sparse records.
members_kept(X, #m{gp = #gvtp{groups = Groups}, planned = Planned} = M) ->
    case [I || I <- rw_regroup:members(Groups), not is_map_key({X, I}, Planned)] of
        [] -> M;
        Unkept -> fail(M, {group_member_record_not_kept, X, Unkept})
    end.

keep(false, _Rows, M) -> M;
keep(true, Rows, #m{planned = P} = M) -> M#m{planned = lists:foldl(fun({Key, _, _}, Acc) -> Acc#{Key => true} end, P, Rows)}.

regroup(X, #m{cal = Cal} = M0) ->
    End = rw_sync:end_t(Cal),
    case rw_sync:period(Cal) of
        0 -> M0;
        P when X rem P =/= 0; X + P >= End -> M0;
        P ->
            M = members_kept(X, M0),
            #m{met = Met0, gp = #gvtp{groups = Groups} = Gp, records = R, scene = #scene{spheres = Spheres}} = M,
            Met = maps:from_list([{Pair, true} || {Pair, T} <- maps:to_list(Met0), T >= X - P]),
            %% (as rw_gvt: only the bodies the plan needs)
            Wanted = rw_regroup:wanted(Met, Groups),
            Bodies = [{I, Rad, Pos, V} || #sphere{idx = I, radius = Rad} <- Spheres,
                                          Wanted =:= all orelse lists:member(I, Wanted),
                                          {_, Pos, V, _, _} <- [maps:get({X, I}, R)]],
            Pids = maps:from_list([{I, I} || #sphere{idx = I} <- Spheres]),
            {Tell, Groups1} = rw_regroup:decide(Bodies, Met, Pids, Groups),
            At = X + P,
            M1 = lists:foldl(fun({I, Move}, Acc) -> enqueue(gvt, I, {regroup, At, Move}, Acc) end,
                             M#m{met = maps:filter(fun(_, T) -> T >= X - P end, Met0),
                                 regroups = M#m.regroups + length(Tell)}, Tell),
            Unready = case Tell of [] -> Gp#gvtp.unready; _ -> (Gp#gvtp.unready)#{At => [I || {I, _} <- Tell]} end,
            M1#m{gp = Gp#gvtp{groups = Groups1, unready = Unready}}
    end.

add_waiting(At, I, [{A, _} = First | Rest]) when A < At -> [First | add_waiting(At, I, Rest)];
add_waiting(At, I, [{At, Is} | Rest]) -> [{At, [I | Is]} | Rest];
add_waiting(At, I, Later) -> [{At, [I]} | Later].

