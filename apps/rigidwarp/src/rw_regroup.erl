%% Contact groups: which bodies the Time Warp engine steps together as one
%% entity (rw_body with several members, stepped by rw_island). Pure: the
%% GVT process calls it at regroup points with every body's committed
%% state, and writes the moves it returns into the plans table.
%%
%% Bodies in persistent contact belong together: as separate entities they
%% meet at every substep and exchange a TVHT write, an event and an
%% acknowledgement per pair and substep. A group is a connected set of
%% bodies that
%%   join  - touch (centres closer than 1.02 x the sum of their radii) and
%%           move together (relative normal speed below 1/8 of the sum of
%%           their radii per second, 0.1 m/s for two spheres of 0.4 m):
%%           resting or rolling on each other, not bouncing off;
%%   stay  - already share a group and are closer than 1.25 x the sum of
%%           their radii, however they move (hysteresis: a group does not
%%           split and re-form at every jostle);
%% and holds at most Max bodies (a union that would pass it is skipped, in
%% a fixed order), so that groups remain many enough to run in parallel.
%% Tests plan eagerly instead: every pair closer than 3 x the sum of their
%% radii joins, however it moves, so groups form and break up at almost
%% every regroup point.
%% A group's leader is its lowest idx. Grouping never changes the physics,
%% only which process computes it.
-module(rw_regroup).
-export([plan/3, plan/4, moves/3]).
-export_type([body/0, leaders/0, move/0, mode/0]).

%% A body's committed state at the regroup point: idx, radius, position,
%% post-response velocity.
-type body() :: {non_neg_integer(), float(), rw_vec:vec(), rw_vec:vec()}.
%% Each body's group, as the idx of the group's leader (its lowest idx).
-type leaders() :: #{non_neg_integer() => non_neg_integer()}.
%% What a body process does at a regroup point: send its members to their
%% new leaders ([{Member, NewLeader, NewLeaderPid}]) and/or gather a group
%% from the old leaders of its new members.
-type move() :: #{send => [{non_neg_integer(), non_neg_integer(), pid()}], gather => [non_neg_integer()]}.
-type mode() :: persistent | eager.

-define(JOIN, 1.02).
-define(STAY, 1.25).
-define(JOIN_SPEED, 0.125).          % relative normal speed, sums of radii per second
-define(EAGER, 3.0).

%% The groups for the next period, from Bodies and the current groups.
-spec plan([body()], leaders(), pos_integer()) -> leaders().
plan(Bodies, Old, Max) -> plan(Bodies, Old, Max, persistent).

-spec plan([body()], leaders(), pos_integer(), mode()) -> leaders().
plan(Bodies, Old, Max, Mode) ->
    ByIdx = maps:from_list([{I, B} || {I, _, _, _} = B <- Bodies]),
    {Stay, Join} = edges(Bodies, Old, Mode),
    Uf0 = maps:from_list([{I, {I, 1}} || {I, _, _, _} <- Bodies]),
    Uf1 = lists:foldl(fun({A, B}, U) -> union(A, B, Max, U) end, Uf0, Stay),
    Uf = lists:foldl(fun({_, {A, B}}, U) -> union(A, B, Max, U) end, Uf1, lists:sort(Join)),
    %% every group is named by its lowest idx
    Roots = maps:fold(fun(I, _, Acc) ->
                              {R, _} = find(I, Uf),
                              maps:update_with(R, fun(L) -> min(L, I) end, I, Acc)
                      end, #{}, ByIdx),
    maps:map(fun(I, _) -> {R, _} = find(I, Uf), maps:get(R, Roots) end, ByIdx).

%% Who moves at the regroup point: the old leader of every group that
%% changes sends its members to their new leaders, and the leader of every
%% group that is new gathers them from their old leaders. Bodies of a group
%% that stays as it was are not involved. Pids maps idx to body process.
-spec moves(leaders(), leaders(), #{non_neg_integer() => pid()}) -> #{non_neg_integer() => move()}.
moves(Same, Same, _Pids) -> #{};
moves(Old, New, Pids) ->
    OldGroups = groups(Old),
    NewGroups = groups(New),
    Changed = fun(Groups, Other) -> [G || {_, G} <- maps:to_list(Groups), not is_group(G, Other)] end,
    Sends = [{hd(G), #{send => [{M, maps:get(M, New), maps:get(maps:get(M, New), Pids)} || M <- G]}}
             || G <- Changed(OldGroups, NewGroups)],
    Gathers = [{hd(G), #{gather => lists:usort([maps:get(M, Old) || M <- G])}}
               || G <- Changed(NewGroups, OldGroups)],
    lists:foldl(fun({I, Move}, Acc) -> maps:update_with(I, fun(M) -> maps:merge(M, Move) end, Move, Acc) end,
                #{}, Sends ++ Gathers).

%%% Internals

%% Leader => sorted members.
groups(Leaders) ->
    maps:map(fun(_, Ms) -> lists:sort(Ms) end,
             maps:fold(fun(I, L, Acc) -> maps:update_with(L, fun(Ms) -> [I | Ms] end, [I], Acc) end,
                       #{}, Leaders)).

is_group([L | _] = G, Groups) -> maps:get(L, Groups, none) =:= G.

%% Pairs close enough to stay together or to join: bodies sorted by x,
%% each tested against those after it that are closer along x than the
%% largest reach.
edges(Bodies, Old, persistent) ->
    RMax = lists:max([0.0 | [R || {_, R, _, _} <- Bodies]]),
    ByX = lists:sort([{X, B} || {_, _, {X, _, _}, _} = B <- Bodies]),
    sweep(ByX, 2.0 * RMax * ?STAY, Old, [], []);
edges(Bodies, _Old, eager) ->
    {[], [{Dist, {IA, IB}} || {IA, RA, PA, _} <- Bodies, {IB, RB, PB, _} <- Bodies, IA < IB,
                              Dist <- [rw_vec:len(rw_vec:sub(PB, PA))], Dist < ?EAGER * (RA + RB)]}.

sweep([], _Reach, _Old, Stay, Join) -> {Stay, Join};
sweep([{X, A} | Rest], Reach, Old, Stay, Join) ->
    {S, J} = near(Rest, X + Reach, Reach, A, Old, Stay, Join),
    sweep(Rest, Reach, Old, S, J).

%% (most bodies within reach along x are far along y or z: two comparisons
%% reject them before any distance is computed)
near([{XB, B} | Rest], XMax, Reach, {IA, RA, {_, YA, ZA} = PA, VA} = A, Old, Stay, Join) when XB < XMax ->
    case B of
        {_, _, {_, YB, ZB}, _} when abs(YB - YA) >= Reach; abs(ZB - ZA) >= Reach ->
            near(Rest, XMax, Reach, A, Old, Stay, Join);
        {IB, RB, PB, VB} ->
            Sum = RA + RB,
            D = rw_vec:sub(PB, PA),
            Dist = rw_vec:len(D),
            Same = maps:get(IA, Old) =:= maps:get(IB, Old),
            Pair = {min(IA, IB), max(IA, IB)},
            if
                Same, Dist < ?STAY * Sum ->
                    near(Rest, XMax, Reach, A, Old, [Pair | Stay], Join);
                not Same, Dist < ?JOIN * Sum, Dist > 0.0 ->
                    Closing = abs(rw_vec:dot(rw_vec:sub(VB, VA), D)) / Dist,
                    case Closing < ?JOIN_SPEED * Sum of
                        true -> near(Rest, XMax, Reach, A, Old, Stay, [{Dist, Pair} | Join]);
                        false -> near(Rest, XMax, Reach, A, Old, Stay, Join)
                    end;
                true ->
                    near(Rest, XMax, Reach, A, Old, Stay, Join)
            end
    end;
near(_, _XMax, _Reach, _A, _Old, Stay, Join) -> {Stay, Join}.

%% Union-find over idx => {Parent, Size} (the smaller tree goes under the
%% larger); a union that would make a group larger than Max is skipped.
find(I, Uf) ->
    case maps:get(I, Uf) of
        {I, Size} -> {I, Size};
        {P, _} -> find(P, Uf)
    end.

union(A, B, Max, Uf) ->
    case {find(A, Uf), find(B, Uf)} of
        {{R, _}, {R, _}} -> Uf;
        {{RA, SA}, {RB, SB}} when SA + SB =< Max ->
            {Root, Child} = case SA >= SB of true -> {RA, RB}; false -> {RB, RA} end,
            Uf#{Root := {Root, SA + SB}, Child := {Root, 0}};
        _ -> Uf
    end.
