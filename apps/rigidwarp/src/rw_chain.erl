%% An entity's step ahead (pure): its members integrated substep by substep
%% from their states at LVT up to LVT_ub, assuming no contact with the
%% outside other than those already known, as the island steps them
%% (rw_island), with the post-response velocities at each sync point passed
%% on the way (to commit once the step is written).
-module(rw_chain).
-include("rigidwarp.hrl").
-export([run/5, pack/2]).
-export_type([context/0, passed/0]).

%% What a step needs besides the states: the model, the substep, the
%% members' post-response velocities at the point where their group was
%% formed (they come from their old entities), the known contacts and the
%% sync calendar.
-type context() :: {#model{}, pos_integer(), none | {non_neg_integer(), tuple()}, rw_timeline:timeline(),
                    rw_sync:calendar()}.
%% A sync point passed: the members' states and post-response velocities.
-type passed() :: {non_neg_integer(), tuple(), tuple()}.

%% The members' states after T up to Last (per member, rw_states:packed()
%% of one state per substep), the sync points passed on the way, and the
%% island with its neighbour list. A body alone keeps its states in a list
%% and packs them at the end (a step of at most a stride); a group appends
%% each member's states to a binary as it computes them, so that the
%% states of a long step are never on the heap for the garbage collector
%% to copy.
-spec run(non_neg_integer(), tuple(), non_neg_integer(), context(), rw_island:island()) ->
          {[passed()], [rw_states:packed()], rw_island:island()}.
run(T, {St}, Last, {M, _, _, _, _} = Ctx, Island0) ->
    {Passed, States, Island} = alone(T, St, Last, Ctx, Island0, [], []),
    {Passed, [pack(States, M)], Island};
run(T, States, Last, {#model{rotation = Rot, ccd = Ccd}, _, _, _, _} = Ctx, Island0) ->
    {Passed, Bins, Island} = chain(T, States, Last, Ctx, Island0, [], [<<>> || _ <- tuple_to_list(States)]),
    {Passed, [rw_states:seal(Bin, Rot, Ccd) || Bin <- Bins], Island}.

%% States packed (with CCD, with their free displacements).
-spec pack([#st{}, ...], #model{}) -> rw_states:packed().
pack(States, #model{rotation = Rot, ccd = false}) -> rw_states:pack(States, undefined, Rot, false);
pack(States, #model{rotation = Rot} = M) -> rw_states:pack(States, [disp(St, M) || St <- States], Rot, true).

%% Bin with St appended (and with CCD its free displacement).
add(Bin, St, #model{rotation = Rot} = M) -> rw_states:append(Bin, St, disp(St, M), Rot).

%% What the packed states hold of St's free displacement: with CCD, the
%% displacement; without, nothing.
disp(_St, #model{ccd = false}) -> undefined;
disp(St, M) -> rw_integrate:free_displacement(M, St).

%% Each member's binary with its state in States appended.
add_all(_K, _States, [], _M) -> [];
add_all(K, States, [Bin | Bins], M) -> [add(Bin, element(K, States), M) | add_all(K + 1, States, Bins, M)].

%% A body on its own, the hot path of free flight.
alone(T, _St, Last, _Ctx, Island, Passed, Acc) when T >= Last ->
    {lists:reverse(Passed), lists:reverse(Acc), Island};
alone(T, St, Last, {M, Dt, Base, TL, Cal} = Ctx, Island0, Passed, Acc) ->
    {{V, W, U} = Post, Island} = case Base of
                                     {T, {BasePost}} -> {BasePost, Island0};
                                     _ -> rw_island:post(Island0, St, rw_timeline:external(T, TL))
                                 end,
    Next = rw_integrate:advance(M, St, V, W, U),
    Passed1 = case rw_sync:is_sync(T, Cal) of
                  true -> [{T, {St}, {Post}} | Passed];
                  false -> Passed
              end,
    alone(T + Dt, Next, Last, Ctx, Island, Passed1, [Next | Acc]).

chain(T, _States, Last, _Ctx, Island, Passed, Bins) when T >= Last ->
    {lists:reverse(Passed), Bins, Island};
chain(T, States, Last, {M, Dt, Base, TL, Cal} = Ctx, Island, Passed, Bins) ->
    {Posts, Next, Island1} =
        case Base of
            {T, BasePosts} -> {BasePosts, rw_island:advance(M, States, BasePosts), Island};
            _ -> rw_island:step(Island, States, rw_timeline:external(T, TL))
        end,
    Passed1 = case rw_sync:is_sync(T, Cal) of
                  true -> [{T, States, Posts} | Passed];
                  false -> Passed
              end,
    chain(T + Dt, Next, Last, Ctx, Island1, Passed1, add_all(1, Next, Bins, M)).
