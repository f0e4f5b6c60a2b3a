%% The TVHT plan of a write, computed afresh and from the writer's last
%% plan (write/8): the second covers every cell each member's states touch
%% at every substep, as the first does.
-module(rw_tvht_plan_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("rw_physics/include/rw_physics.hrl").

-define(CELL, 2.5).
-define(DT, 1).

model() -> #model{}.

spheres(N) -> list_to_tuple([#sphere{idx = I, id = integer_to_binary(I), radius = 0.5, mass = 1.0, inv_mass = 1.0,
                                     inv_inertia = 10.0} || I <- lists:seq(1, N)]).

%% Member K's states: Len substeps from P moving by V per substep.
steps(Starts, Len) ->
    [rw_states:pack([#st{p = rw_vec:add(P, rw_vec:scale(V, float(I))), v = V} || I <- lists:seq(0, Len - 1)],
                    undefined, false, false)
     || {P, V} <- Starts].

%% {Cell, Idx, T} for every substep T a member's span in a cell holds.
occupancy(Plan) ->
    lists:usort([{C, I, T} || {_, _, Spans} <- Plan, {C, _, _, Ms} <- Spans, {I, A, B} <- Ms,
                              T <- lists:seq(A, B, ?DT)]).

%% What each member's states touch: {Cell, Idx, T}.
touched(Spheres, Steps, T0) ->
    lists:usort([{C, I, T0 + (K - 1) * ?DT}
                 || {#sphere{idx = I, radius = R}, Packed} <- lists:zip(tuple_to_list(Spheres), Steps),
                    K <- lists:seq(1, rw_states:count(Packed)),
                    C <- rw_hash:cells(rw_shape:sphere_aabb(rw_states:position(Packed, K), R), ?CELL)]).

resting_pile_reuses_its_plan_test() ->
    Sp = spheres(3),
    Starts = [{{0.1, 0.2, 0.3}, {0.0, 0.0, 0.0}}, {{1.1, 0.2, 0.3}, {0.0, -0.001, 0.0}},
              {{2.6, 0.2, 0.3}, {0.001, 0.0, 0.0}}],
    {W1, P1, Cache} = rw_tvht_plan:write(self(), 10, Sp, steps(Starts, 4), model(), {?CELL, ?DT}, 4, none),
    ?assertEqual(rw_tvht_plan:write(self(), 10, Sp, steps(Starts, 4), model(), {?CELL, ?DT}, 4), {W1, P1}),
    ?assertNotEqual(none, Cache),
    %% the next write, later, in the same cells: the cached plan, new times
    Later = [{rw_vec:add(P, rw_vec:scale(V, 4.0)), V} || {P, V} <- Starts],
    Steps2 = steps(Later, 6),
    {W2, P2, Cache} = rw_tvht_plan:write(self(), 14, Sp, Steps2, model(), {?CELL, ?DT}, 4, Cache),
    {W2, Fresh} = rw_tvht_plan:write(self(), 14, Sp, Steps2, model(), {?CELL, ?DT}, 4),
    ?assertEqual(Fresh, P2),
    ?assertEqual(touched(Sp, Steps2, 14), [X || X <- occupancy(P2), lists:member(X, touched(Sp, Steps2, 14))]).

%% A member that moves to other cells makes a fresh plan; whatever the
%% cache, every cell a member touches is in the plan at that substep.
moving_members_plan_afresh_test() ->
    rand:seed(exsss, 7),
    Sp = spheres(5),
    {_, _, Reused} =
        lists:foldl(
          fun(Round, {Cache, Prev, Hits}) ->
                  %% every other round the members start where they did
                  %% before, moving little: their boxes may be the same
                  Starts = case Round rem 2 of
                               0 -> [{P, rw_vec:scale(V, 0.1)} || {P, V} <- Prev];
                               1 -> [{{rand:uniform() * 6.0, rand:uniform() * 6.0, 0.0},
                                      {(rand:uniform() - 0.5) * 0.2 * (Round rem 3), 0.0, 0.0}} || _ <- lists:seq(1, 5)]
                           end,
                  Steps = steps(Starts, 1 + rand:uniform(8)),
                  T0 = Round * 10,
                  {W, Plan, Cache1} = rw_tvht_plan:write(self(), T0, Sp, Steps, model(), {?CELL, ?DT}, 4, Cache),
                  {W, _} = rw_tvht_plan:write(self(), T0, Sp, Steps, model(), {?CELL, ?DT}, 4),
                  Occ = occupancy(Plan),
                  [?assert(lists:member(X, Occ)) || X <- touched(Sp, Steps, T0)],
                  {Cache1, Starts, Hits + case Cache =/= none andalso Cache1 =:= Cache of true -> 1; false -> 0 end}
          end, {none, [], 0}, lists:seq(1, 200)),
    ?assert(Reused > 10).

%% With CCD the plan is always made afresh.
ccd_plans_afresh_test() ->
    Sp = spheres(1),
    St = #st{p = {0.0, 0.0, 0.0}, v = {1.0, 0.0, 0.0}},
    Packed = rw_states:pack([St], [{0.001, 0.0, 0.0}], false, true),
    {_, _, none} = rw_tvht_plan:write(self(), 0, Sp, [Packed], (model())#model{ccd = true}, {?CELL, ?DT}, 4, none).

%% A pile in which a few members cross cell borders between writes: the
%% plan made from the last one, with those members moved in it, is
%% write/7's term for term, and it is made so most of the time.
moved_members_move_in_the_last_plan_test() ->
    rand:seed(exsss, 11),
    N = 40,
    Sp = spheres(N),
    Jump = fun() -> (rand:uniform() - 0.5) * ?CELL end,
    Starts0 = [{{rand:uniform() * 10.0, rand:uniform() * 10.0, rand:uniform() * 2.0}, {0.0, 0.0, 0.0}}
               || _ <- lists:seq(1, N)],
    {_, _, Moved} =
        lists:foldl(
          fun(Round, {Cache, Starts, Count}) ->
                  Starts1 = [case rand:uniform(10) of
                                 1 -> {rw_vec:add(P, {Jump(), Jump(), Jump()}), {0.0, 0.001 * Jump(), 0.0}};
                                 _ -> {P, V}
                             end || {P, V} <- Starts],
                  Steps = steps(Starts1, 1 + Round rem 4),
                  T0 = Round * 10,
                  {W, Plan, Cache1} = rw_tvht_plan:write(self(), T0, Sp, Steps, model(), {?CELL, ?DT}, 4, Cache),
                  ?assertEqual(rw_tvht_plan:write(self(), T0, Sp, Steps, model(), {?CELL, ?DT}, 4), {W, Plan}),
                  {Cache1, Starts1, Count + case Cache =/= none andalso Cache1 =/= none andalso Cache1 =/= Cache of
                                                true -> 1;
                                                false -> 0
                                            end}
          end, {none, Starts0, 0}, lists:seq(1, 100)),
    ?assert(Moved > 50).

%% With CCD, a sphere swept across many cells at every substep is planned
%% in the cells it can touch on the way (rw_hash:swept_cells/4): each of
%% them at its substep, and far fewer than its swept boxes hold (a
%% diagonal move's box grows as the cube of its length).
fast_diagonal_sphere_test() ->
    Sp = spheres(1),
    V = {30.0, 30.0, -30.0},
    N = 5,
    Packed = rw_states:pack([#st{p = rw_vec:scale(V, float(I)), v = V} || I <- lists:seq(0, N - 1)],
                            [V || _ <- lists:seq(1, N)], false, true),
    {_, Plan} = rw_tvht_plan:write(self(), 0, Sp, [Packed], (model())#model{ccd = true}, {?CELL, ?DT}, 4),
    Swept = [{rw_states:position(Packed, K), rw_states:displacement(Packed, K), K - 1} || K <- lists:seq(1, N)],
    Occupied = occupancy(Plan),
    [?assert(lists:member({C, 1, T}, Occupied)) || {P, D, T} <- Swept, C <- rw_hash:swept_cells(P, D, 0.5, ?CELL)],
    Planned = lists:usort([C || {_, Cells, _} <- Plan, C <- Cells]),
    Boxes = lists:usort([C || {P, D, _} <- Swept, C <- rw_hash:cells(rw_shape:swept_aabb(P, D, 0.5), ?CELL)]),
    ?assert(10 * length(Planned) < length(Boxes)).

%% The buckets compare boxes on an integer grid: each holds its exact box
%% (else a probe would call two touching writes apart), at any magnitude,
%% and the grid is a power of two near 64 per cell, never below 1.
on_grid_holds_the_box_test() ->
    rand:seed(exsss, {7, 8, 9}),
    lists:foreach(
      fun(CellSize) ->
              G = rw_tvht_plan:grid(CellSize),
              ?assert(G >= 1.0),
              ?assertEqual(G, math:pow(2, round(math:log2(G)))),
              ?assert(CellSize * G =< 128 orelse G =:= 1.0),
              lists:foreach(
                fun(_) ->
                        [A, B, C, D, E, F] = [rw_test_lib:awkward_double() || _ <- lists:seq(1, 6)],
                        Box = {min(A, B), min(C, D), min(E, F), max(A, B), max(C, D), max(E, F)},
                        {L0, L1, L2, H0, H1, H2} = rw_tvht_plan:on_grid(Box, G),
                        {X0, Y0, Z0, X1, Y1, Z1} = Box,
                        [?assert(holds(Lo, Hi, Min, Max, G)) || {Lo, Hi, Min, Max} <- [{L0, H0, X0, X1}, {L1, H1, Y0, Y1},
                                                                                     {L2, H2, Z0, Z1}]]
                end, lists:seq(1, 2000))
      end, [0.001, 0.3, 1.25, 2.5, 64.0, 1.0e6]),
    %% a box on the grid is as tight as the grid allows
    ?assertEqual({-1, 0, 64, 1, 0, 65}, rw_tvht_plan:on_grid({-0.01, 0.0, 1.0, 0.01, 0.0, 1.01}, 64.0)),
    ?assertEqual({0, 0, 0, 0, 0, 0}, rw_tvht_plan:on_grid({-0.0, -0.0, -0.0, -0.0, -0.0, -0.0}, 64.0)).

%% Min..Max within Lo..Hi on a grid of 1/G: compared exactly (the products
%% of a power of two are exact but for overflow, taken by the grid's ends).
holds(Lo, Hi, Min, Max, G) ->
    is_integer(Lo) andalso is_integer(Hi) andalso
        (Lo =< -16#100000000000000 orelse Min >= 1.0e300 orelse Lo =< Min * G) andalso
        (Hi >= 16#100000000000000 orelse Max =< -1.0e300 orelse Hi >= Max * G) andalso
        abs(Lo) =< 16#100000000000000 andalso abs(Hi) =< 16#100000000000000.
