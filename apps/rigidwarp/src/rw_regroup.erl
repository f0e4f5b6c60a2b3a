%% Contact groups: which bodies the Time Warp engine steps together as one
%% entity (rw_entity with several members, stepped by rw_island). Pure: the
%% GVT process calls it at regroup points with every body's committed
%% state, and sends each entity whose group changes its move.
%%
%% Bodies in persistent contact belong together: as separate entities they
%% meet at every substep and exchange a TVHT write, an event and an
%% acknowledgement per pair and substep. A group is a connected set of
%% bodies that
%%   meet  - met at many substeps lately (the entities say so in #sim.met:
%%           rw_neighbour:touch/4) and are closer than 1.25 x the sum of their
%%           radii: resting, rolling or pressing on each other, or bouncing
%%           on each other again and again as Cylinders' layers do when they
%%           land; a bounce in a gas of spheres is over in a few substeps and
%%           joins nothing (grouping every pair near each other would
%%           regroup a gas at every regroup point, for nothing);
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
%%
%% decide/4 is what the GVT process does at a regroup point: the groups
%% from the committed states, and whom to tell what; it carries that out.
-module(rw_regroup).
-export([max_allowed/0, new/3, new/4, by_site/2, quiet/2, wanted/2, reads_only_some/2, members/1, decide/4, plan/4, plan/5, moves/3]).
-export_type([body/0, leaders/0, move/0, pairs/0, groups/0]).

%% A body's committed state at the regroup point: idx, radius, position,
%% post-response velocity.
-type body() :: {non_neg_integer(), float(), rw_vec:vec(), rw_vec:vec()}.
%% Each body's group, as the idx of the group's leader (its lowest idx).
-type leaders() :: #{non_neg_integer() => non_neg_integer()}.
%% What a body process does at a regroup point: send its members to their
%% new leaders ([{Member, NewLeader, NewLeaderPid}], and for each of those
%% leaders the old leaders it gathers from, which it learns from the
%% bundles) and/or gather a group from the old leaders of its new members.
-type move() :: #{send => [{non_neg_integer(), non_neg_integer(), pid()}],
                  expect => #{non_neg_integer() => [non_neg_integer()]},
                  gather => [non_neg_integer()]}.
%% Pairs of bodies {A, B}, A less than B.
-type pairs() :: #{{non_neg_integer(), non_neg_integer()} => true}.

%% The most bodies a group may hold at all (the run option group_max and
%% --group-max refuse more): the C island steps a group of 128 or more on
%% a dirty scheduler, reading and building every member's terms at each
%% call, some 8 substeps of 3 ms each at this size; larger groups have not
%% been measured.
-define(MAX_ALLOWED, 4096).

-define(NEAR, 1.25).
-define(EAGER, 3.0).

%% The largest group_max a run takes.
-spec max_allowed() -> pos_integer().
max_allowed() -> ?MAX_ALLOWED.

%% The groups of a simulation as planned last: every body alone at first.
-record(groups, {
    leaders :: leaders(),
    %% the bodies in groups of two or more, as a set
    members = #{} :: #{non_neg_integer() => true},
    max :: pos_integer(),
    mode :: persistent | eager,              % eager: tests only
    %% under gravity: a body closing in on a group joins it (landing)
    landing = false :: boolean(),
    %% over several nodes, each body's node: a group is one process, so
    %% only bodies of one node are grouped
    sites = none :: none | #{non_neg_integer() => non_neg_integer()}
}).
-opaque groups() :: #groups{}.

-spec new([non_neg_integer()], pos_integer(), persistent | eager) -> groups().
new(Idxs, Max, Mode) -> new(Idxs, Max, Mode, false).

%% Landing: bodies fall (the scene has gravity), so a body closing in on a
%% group comes to rest on it, and joins it before it touches it. Without
%% gravity a body that meets a group bounces off and flies on: it joins
%% only once it has met a member often.
-spec new([non_neg_integer()], pos_integer(), persistent | eager, boolean()) -> groups().
new(Idxs, Max, Mode, Landing) ->
    #groups{leaders = maps:from_list([{I, I} || I <- Idxs]), max = Max, mode = Mode, landing = Landing}.

%% Group only bodies on one node: Sites maps each body's idx to its node.
-spec by_site(groups(), #{non_neg_integer() => non_neg_integer()}) -> groups().
by_site(G, Sites) -> G#groups{sites = Sites}.

%% Without a group and without a pair that met often nothing can change:
%% no need to read the committed states.
-spec quiet(pairs(), groups()) -> boolean().
quiet(Met, #groups{mode = Mode, members = Members}) ->
    Mode =:= persistent andalso map_size(Members) =:= 0 andalso map_size(Met) =:= 0.

%% The bodies whose committed states decide/4 needs, in idx order: every
%% body when one may land on a group (or eagerly, in tests), else only the
%% members of groups and the bodies of pairs that met. Any other is alone
%% and met nobody, and stays alone: in a gas of tens of thousands of
%% spheres the GVT process, which every body waits for, reads a few
%% hundred records at a regroup point instead of all of them.
-spec wanted(pairs(), groups()) -> all | [non_neg_integer()].
wanted(_Met, #groups{mode = eager}) -> all;
wanted(_Met, #groups{landing = true, members = Members}) when map_size(Members) > 0 -> all;
wanted(Met, #groups{members = Members}) -> lists:sort(maps:keys(seen(Met, Members))).

%% Does wanted/2 never ask for every body, with groups planned in Mode and
%% Landing as in new/4? Then a body alone that met nobody lately need not
%% keep its record at a regroup point (rw_sim's sparse records).
-spec reads_only_some(persistent | eager, boolean()) -> boolean().
reads_only_some(Mode, Landing) -> Mode =:= persistent andalso not Landing.

%% The bodies in groups of two or more, in idx order.
-spec members(groups()) -> [non_neg_integer()].
members(#groups{members = Members}) -> lists:sort(maps:keys(Members)).

%% At a regroup point: the groups from every body's committed state there
%% and the pairs that met often lately, and what each entity whose group
%% changes must do at the next regroup point ({Idx, Move}: tell the process
%% of body Idx). Pids maps idx to body process.
-spec decide([body()], pairs(), #{non_neg_integer() => pid()}, groups()) -> {[{non_neg_integer(), move()}], groups()}.
decide(Bodies, Met, Pids, #groups{leaders = Old, members = Members, max = Max, mode = Mode, landing = Landing,
                                  sites = Sites} = G) ->
    Pairs = case Mode of eager -> eager; persistent -> Met end,
    %% the new leaders of Bodies, wanted/2's bodies or more: every other
    %% body is alone and stays so
    Planned = case Sites of
                  none -> plan(Bodies, Old, Members, Max, Pairs, Landing);
                  _ ->
                      BySite = maps:groups_from_list(fun({I, _, _, _}) -> maps:get(I, Sites) end, Bodies),
                      maps:fold(fun(_, Share, Acc) -> maps:merge(Acc, plan(Share, Old, Members, Max, Pairs, Landing)) end,
                                #{}, BySite)
              end,
    %% (Planned names every body, or some: wanted/2)
    Before = case map_size(Planned) =:= map_size(Old) of
                 true -> Old;
                 false -> maps:with(maps:keys(Planned), Old)
             end,
    Moves = moves(Before, Planned, Pids),
    New = maps:merge(Old, Planned),
    {[{I, Move} || {I, #{send := _} = Move} <- maps:to_list(Moves)],
     G#groups{leaders = New, members = grouped(Planned)}}.

%% The groups from Bodies, the current groups and the pairs that met at
%% many substeps lately (eager: tests).
-spec plan([body()], leaders(), pos_integer(), pairs() | eager) -> leaders().
plan(Bodies, Old, Max, Met) -> plan(Bodies, Old, Max, Met, false).

%% ... and with Landing, bodies closing in on a group join it (new/4).
-spec plan([body()], leaders(), pos_integer(), pairs() | eager, boolean()) -> leaders().
plan(Bodies, Old, Max, Met, Landing) -> plan(Bodies, Old, grouped(Old), Max, Met, Landing).

plan(Bodies, Old, Grouped, Max, Met, Landing) ->
    %% (a body alone that met nobody stays alone, unless it is landing on
    %% a group: only the others can have an edge)
    {Stay, Join} = edges(candidates(Bodies, Grouped, Met, Landing), Old, Grouped, Met, Landing),
    %% union-find over the bodies with an edge (any other is its own root)
    Uf1 = lists:foldl(fun({A, B}, U) -> union(A, B, Max, U) end, #{}, Stay),
    Uf = lists:foldl(fun({_, {A, B}}, U) -> union(A, B, Max, U) end, Uf1, lists:sort(Join)),
    %% every group is named by its lowest idx
    Roots = maps:fold(fun(I, _, Acc) ->
                              {R, _} = find(I, Uf),
                              maps:update_with(R, fun(L) -> min(L, I) end, I, Acc)
                      end, #{}, Uf),
    maps:from_list([{I, case Uf of
                            #{I := _} -> {R, _} = find(I, Uf), maps:get(R, Roots);
                            _ -> I
                        end} || {I, _, _, _} <- Bodies]).

%% Who moves at the regroup point: the old leader of every group that
%% changes sends its members to their new leaders, and the leader of every
%% group that is new gathers them from their old leaders. Bodies of a group
%% that stays as it was are not involved. Pids maps idx to body process.
-spec moves(leaders(), leaders(), #{non_neg_integer() => pid()}) -> #{non_neg_integer() => move()}.
moves(Same, Same, _Pids) -> #{};
moves(Old, New, Pids) ->
    %% The groups that change are those that lose or gain a member: those
    %% led, before or after, by the old or new leader of a body whose
    %% leader changes (a leader is its group's lowest idx). Only they are
    %% gathered into lists: at a regroup point of a pile of hundreds of
    %% spheres a few groups change.
    Changed = maps:fold(fun(I, L, Acc) ->
                                case maps:get(I, Old) of
                                    L -> Acc;
                                    L0 -> Acc#{L0 => true, L => true}
                                end
                        end, #{}, New),
    Of = fun(Leaders) -> groups(maps:filter(fun(_, L) -> is_map_key(L, Changed) end, Leaders)) end,
    Gathers = [{hd(G), #{gather => lists:usort([maps:get(M, Old) || M <- G])}} || G <- maps:values(Of(New))],
    From = maps:from_list([{L, F} || {L, #{gather := F}} <- Gathers]),
    Sends = [{hd(G), #{send => [{M, maps:get(M, New), maps:get(maps:get(M, New), Pids)} || M <- G],
                       expect => maps:with([maps:get(M, New) || M <- G], From)}}
             || G <- maps:values(Of(Old))],
    lists:foldl(fun({I, Move}, Acc) -> maps:update_with(I, fun(M) -> maps:merge(M, Move) end, Move, Acc) end,
                #{}, Sends ++ Gathers).

%%% Internals

%% The bodies in a group of two or more, as a set.
grouped(Old) ->
    maps:fold(fun(I, L, Acc) when I =/= L -> Acc#{I => true, L => true};
                 (_, _, Acc) -> Acc
              end, #{}, Old).

candidates(Bodies, _Grouped, eager, _Landing) -> Bodies;
candidates(Bodies, Grouped, Met, Landing) ->
    case Landing andalso map_size(Grouped) > 0 of
        true -> Bodies;
        false ->
            Seen = seen(Met, Grouped),
            [B || {I, _, _, _} = B <- Bodies, is_map_key(I, Seen)]
    end.

%% The bodies of a group or of a pair that met, as a set.
seen(Met, Grouped) -> maps:fold(fun({A, B}, _, Acc) -> Acc#{A => true, B => true} end, Grouped, Met).

%% Leader => sorted members.
groups(Leaders) ->
    maps:map(fun(_, Ms) -> lists:sort(Ms) end,
             maps:fold(fun(I, L, Acc) -> maps:update_with(L, fun(Ms) -> [I | Ms] end, [I], Acc) end,
                       #{}, Leaders)).

%% Pairs close enough to stay together or to join: a pair that met often,
%% or with Landing a body closing in on a group's member (a sphere landing
%% on a pile joins it before it touches, instead of meeting the group at
%% every substep until it has met it often enough).
edges(Bodies, Old, Grouped0, Met, Landing) ->
    Reach = case Met of eager -> ?EAGER; _ -> ?NEAR end,
    Grouped = case Met =/= eager andalso Landing of
                  false -> #{};
                  true -> Grouped0
              end,
    Motion = case map_size(Grouped) of
                 0 -> #{};
                 _ -> maps:from_list([{I, {P, V}} || {I, _, P, V} <- Bodies])
             end,
    lists:foldl(fun({{A, B} = Pair, Dist, Sum}, {S, J}) ->
                        case maps:get(A, Old) =:= maps:get(B, Old) of
                            true when Dist < ?NEAR * Sum -> {[Pair | S], J};
                            false when Met =:= eager -> {S, [{Dist, Pair} | J]};
                            false when Dist < ?NEAR * Sum ->
                                case is_map_key(Pair, Met) orelse closing(A, B, Grouped, Motion) of
                                    true -> {S, [{Dist, Pair} | J]};
                                    false -> {S, J}
                                end;
                            _ -> {S, J}
                        end
                end, {[], []}, close(Bodies, Reach)).

%% One of A and B is in a group and they move towards each other.
closing(A, B, Grouped, Motion) ->
    case is_map_key(A, Grouped) orelse is_map_key(B, Grouped) of
        true ->
            {PA, VA} = maps:get(A, Motion),
            {PB, VB} = maps:get(B, Motion),
            rw_vec:dot(rw_vec:sub(VB, VA), rw_vec:sub(PB, PA)) < 0.0;
        false -> false
    end.

%% Pairs {{A, B}, Distance, SumOfRadii} closer than F x the sum of their
%% radii, found by sweep and prune: within the largest reach along x, y and
%% z. (The GVT process runs this at every regroup point, which every body
%% waits for: rw_broadphase:sweep/2 is its hot loop.)
close(Bodies, F) ->
    RMax = lists:max([0.0 | [R || {_, R, _, _} <- Bodies]]),
    Reach = 2.0 * RMax * F,
    rw_broadphase:sweep([{X, I, Y, Z, R, Reach} || {I, R, {X, Y, Z}, _} <- Bodies], {distance, F}).

%% Union-find over idx => {Parent, Size} (the smaller tree goes under the
%% larger); a union that would make a group larger than Max is skipped.
find(I, Uf) ->
    case Uf of
        #{I := {I, Size}} -> {I, Size};
        #{I := {P, _}} -> find(P, Uf);
        _ -> {I, 1}
    end.

union(A, B, Max, Uf) ->
    case {find(A, Uf), find(B, Uf)} of
        {{R, _}, {R, _}} -> Uf;
        {{RA, SA}, {RB, SB}} when SA + SB =< Max ->
            {Root, Child} = case SA >= SB of true -> {RA, RB}; false -> {RB, RA} end,
            Uf#{Root => {Root, SA + SB}, Child => {Root, 0}};
        _ -> Uf
    end.
