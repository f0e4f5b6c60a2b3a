%% Contact groups: who joins, who stays, the cap, and who moves.
-module(rw_regroup_tests).
-include_lib("eunit/include/eunit.hrl").

%% Bodies of radius 0.5 on the x axis: {Idx, X, Vx}.
bodies(Specs) -> [{I, 0.5, {X, 0.0, 0.0}, {V, 0.0, 0.0}} || {I, X, V} <- Specs].

alone(Bodies) -> maps:from_list([{I, I} || {I, _, _, _} <- Bodies]).

%% Every neighbour pair of Bodies (by idx) said it met often.
met(Bodies) ->
    Idxs = lists:sort([I || {I, _, _, _} <- Bodies]),
    maps:from_list([{{A, B}, true} || {A, B} <- lists:zip(lists:droplast(Idxs), tl(Idxs))]).

plan(Bodies, Old, Max) -> rw_regroup:plan(Bodies, Old, Max, met(Bodies)).

bodies_that_met_join_test() ->
    B = bodies([{3, 0.0, 0.0}, {7, 0.99, 0.0}, {9, 5.0, 0.0}]),
    ?assertEqual(#{3 => 3, 7 => 3, 9 => 9}, plan(B, alone(B), 64)).

bodies_that_met_join_however_fast_they_move_test() ->
    B = bodies([{3, 0.0, -10.0}, {7, 1.2, 10.0}]),
    ?assertEqual(#{3 => 3, 7 => 3}, plan(B, alone(B), 64)).

touching_without_meeting_joins_nothing_test() ->
    B = bodies([{3, 0.0, 0.0}, {7, 0.99, 0.0}]),
    ?assertEqual(alone(B), rw_regroup:plan(B, alone(B), 64, #{})).

met_but_apart_now_joins_nothing_test() ->
    B = bodies([{3, 0.0, 0.0}, {7, 1.3, 0.0}]),
    ?assertEqual(alone(B), plan(B, alone(B), 64)).

cap_test() ->
    B = bodies([{I, I * 0.99, 0.0} || I <- lists:seq(1, 7)]),
    New = plan(B, alone(B), 3),
    Sizes = maps:values(maps:fold(fun(_, L, Acc) -> maps:update_with(L, fun(N) -> N + 1 end, 1, Acc) end, #{}, New)),
    ?assert(lists:max(Sizes) =< 3),
    ?assert(length(Sizes) =< 4),
    %% each group is named by its lowest member
    [?assert(L =< I) || {I, L} <- maps:to_list(New)].

stay_margin_test() ->
    Together = #{3 => 3, 7 => 3},
    %% apart by 1.2 x the sum of radii: still one group, however they move
    Near = bodies([{3, 0.0, -5.0}, {7, 1.2, 5.0}]),
    ?assertEqual(Together, rw_regroup:plan(Near, Together, 64, #{})),
    Far = bodies([{3, 0.0, 0.0}, {7, 1.3, 0.0}]),
    ?assertEqual(alone(Far), rw_regroup:plan(Far, Together, 64, #{})).

%% Under gravity a body closing in on a group joins it before it has met
%% it; one moving away, or any without gravity, does not.
landing_test() ->
    Pile = #{3 => 3, 5 => 3, 7 => 7},
    Closing = bodies([{3, 0.0, 0.0}, {5, 1.0, 0.0}, {7, 2.2, -2.0}]),
    ?assertEqual(#{3 => 3, 5 => 3, 7 => 3}, rw_regroup:plan(Closing, Pile, 64, #{}, true)),
    ?assertEqual(#{3 => 3, 5 => 3, 7 => 7}, rw_regroup:plan(Closing, Pile, 64, #{}, false)),
    Leaving = bodies([{3, 0.0, 0.0}, {5, 1.0, 0.0}, {7, 2.2, 2.0}]),
    ?assertEqual(#{3 => 3, 5 => 3, 7 => 7}, rw_regroup:plan(Leaving, Pile, 64, #{}, true)),
    %% two lone bodies closing in on each other: no group to land on
    Pair = bodies([{3, 0.0, 1.0}, {7, 1.2, -1.0}]),
    ?assertEqual(alone(Pair), rw_regroup:plan(Pair, alone(Pair), 64, #{}, true)),
    %% too far to join yet
    Far = bodies([{3, 0.0, 0.0}, {5, 1.0, 0.0}, {7, 2.4, -2.0}]),
    ?assertEqual(#{3 => 3, 5 => 3, 7 => 7}, rw_regroup:plan(Far, Pile, 64, #{}, true)).

eager_joins_near_bodies_test() ->
    B = bodies([{3, 0.0, -9.0}, {7, 2.5, 9.0}, {9, 9.0, 0.0}]),
    ?assertEqual(#{3 => 3, 7 => 3, 9 => 9}, rw_regroup:plan(B, alone(B), 64, eager)).

moves_test() ->
    Pids = #{3 => pid3, 7 => pid7, 9 => pid9},
    Old = #{3 => 3, 7 => 7, 9 => 9},
    New = #{3 => 3, 7 => 3, 9 => 9},
    %% every sender also says whom each of its new leaders gathers from
    ?assertEqual(#{3 => #{send => [{3, 3, pid3}], expect => #{3 => [3, 7]}, gather => [3, 7]},
                   7 => #{send => [{7, 3, pid3}], expect => #{3 => [3, 7]}}},
                 rw_regroup:moves(Old, New, Pids)),
    %% and back apart: the leader sends both, 7 gathers itself
    ?assertEqual(#{3 => #{send => [{3, 3, pid3}, {7, 7, pid7}], expect => #{3 => [3], 7 => [3]}, gather => [3]},
                   7 => #{gather => [3]}},
                 rw_regroup:moves(New, Old, Pids)),
    ?assertEqual(#{}, rw_regroup:moves(New, New, Pids)).

%% The GVT process hands decide/4 only the bodies wanted/2 names (a gas
%% of thousands reads a few hundred records); with every body instead,
%% the moves and the groups are the same, round after round, as groups
%% form, grow to the cap and break up.
wanted_bodies_decide_as_all_do_test() ->
    rand:seed(exsss, {24, 11, 26}),
    Partial = [rounds(Landing, Max) || Landing <- [false, true], Max <- [3, 64]],
    %% most rounds read only some of the bodies
    ?assert(lists:sum(Partial) >= 40).

rounds(Landing, Max) ->
    Idxs = lists:seq(1, 60),
    Pids = maps:from_list([{I, {pid, I}} || I <- Idxs]),
    {_, Partial} =
        lists:foldl(
          fun(_, {G, P}) ->
                  Bodies = [{I, 0.5, {8 * rand:uniform(), 8 * rand:uniform(), 0.0},
                             {rand:uniform() - 0.5, rand:uniform() - 0.5, 0.0}} || I <- Idxs],
                  Met = maps:from_list([{{A, B}, true} || {A, _, PA, _} <- Bodies, {B, _, PB, _} <- Bodies, A < B,
                                                         rw_vec:len(rw_vec:sub(PA, PB)) < 1.2,
                                                         rand:uniform() < 0.3]),
                  Some = case rw_regroup:wanted(Met, G) of
                             all -> Bodies;
                             Wanted -> [B || {I, _, _, _} = B <- Bodies, lists:member(I, Wanted)]
                         end,
                  {Tell, G1} = rw_regroup:decide(Bodies, Met, Pids, G),
                  ?assertEqual({Tell, G1}, rw_regroup:decide(Some, Met, Pids, G)),
                  {G1, P + length([x || length(Some) < length(Bodies)])}
          end, {rw_regroup:new(Idxs, Max, persistent, Landing), 0}, lists:seq(1, 20)),
    Partial.
