%% The exact event-driven solver against closed forms.
-module(rw_exact_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).

world(G, E, Planes) -> #{gravity => G, restitution => E, planes => Planes}.
ball(Id, R, M, P, V) -> #{id => Id, r => R, m => M, p => P, v => V}.

near(A, B) -> ?assert(abs(A - B) < 1.0e-12 * max(1.0, abs(A))).

equal_masses_swap_test() ->
    {[{3000, [{a, PA, VA}, {b, PB, VB}]}], [{T, {pair, 1, 2}}]} =
        rw_exact:run(world(undefined, 1.0, []), [ball(a, 0.5, 1.0, {-2.0, 0.0, 0.0}, {1.0, 0.0, 0.0}),
                                                  ball(b, 0.5, 1.0, {2.0, 0.0, 0.0}, {-1.0, 0.0, 0.0})], [3000]),
    near(T, 1.5),
    ?assertBitwise({-1.0, 0.0, 0.0}, VA),
    ?assertBitwise({1.0, 0.0, 0.0}, VB),
    near(element(1, PA), -2.0), near(element(1, PB), 2.0).

unequal_masses_textbook_test() ->
    {[{3000, [{h, _, {V1, _, _}}, {l, _, {V2, _, _}}]}], _} =
        rw_exact:run(world(undefined, 1.0, []), [ball(h, 0.5, 3.0, {-2.0, 0.0, 0.0}, {1.0, 0.0, 0.0}),
                                                  ball(l, 0.5, 1.0, {2.0, 0.0, 0.0}, {-1.0, 0.0, 0.0})], [3000]),
    near(V1, ((3.0 - 1.0) * 1.0 + 2 * 1.0 * -1.0) / 4.0),
    near(V2, ((1.0 - 3.0) * -1.0 + 2 * 3.0 * 1.0) / 4.0).

projectile_closed_form_test() ->
    G = {0.0, -9.81, 0.0},
    {[{1000, [{p, {X, Y, _}, {_, Vy, _}}]}], []} =
        rw_exact:run(world(G, 1.0, []), [ball(p, 0.1, 1.0, {0.0, 0.0, 0.0}, {3.0, 5.0, 0.0})], [1000]),
    near(X, 3.0), near(Y, 5.0 - 9.81 / 2), near(Vy, 5.0 - 9.81).

ball_drop_bounces_test() ->
    G = {0.0, -9.81, 0.0},
    {_, [{T1, {plane, 1, 1}}, {T2, {plane, 1, 1}} | _]} =
        rw_exact:run(world(G, 0.5, [{{0.0, 1.0, 0.0}, 0.0}]), [ball(b, 0.1, 1.0, {0.0, 1.1, 0.0}, {0.0, 0.0, 0.0})],
                     [3000]),
    near(T1, math:sqrt(2 * 1.0 / 9.81)),
    %% up and down again at half the impact speed
    near(T2 - T1, 2 * 0.5 * math:sqrt(2 * 9.81 * 1.0) / 9.81).

ball_drop_comes_to_rest_test() ->
    G = {0.0, -9.81, 0.0},
    {[{3000, [{b, {_, Y, _}, V}]}], Events} =
        rw_exact:run(world(G, 0.5, [{{0.0, 1.0, 0.0}, 0.0}]), [ball(b, 0.1, 1.0, {0.0, 1.1, 0.0}, {0.0, 0.0, 0.0})],
                     [3000]),
    ?assert(length(Events) < 100),
    near(Y, 0.1),
    ?assertBitwise({0.0, 0.0, 0.0}, V).

cradle_passes_momentum_through_test() ->
    Balls = [ball(list_to_atom([$a + I]), 0.5, 1.0, {float(I), 0.0, 0.0}, {0.0, 0.0, 0.0}) || I <- lists:seq(0, 4)],
    Striker = ball(s, 0.5, 1.0, {-1.5, 0.0, 0.0}, {1.0, 0.0, 0.0}),
    {[{2000, Final}], _} = rw_exact:run(world(undefined, 1.0, []), [Striker | Balls], [2000]),
    Vs = [element(1, V) || {_, _, V} <- Final],
    ?assertBitwise([0.0, 0.0, 0.0, 0.0, 0.0, 1.0], Vs).

%%% Boxes: containers (six inward half-spaces) and solid boxes (six bounded faces)

walls_of_fixtures_test() ->
    ?assertBitwise([{{0.0, 1.0, 0.0}, 2.0}], rw_exact:walls({plane, {0.0, 1.0, 0.0}, 2.0})),
    Hollow = rw_exact:walls({box, {1.0, 0.0, 0.0}, {2.0, 3.0, 4.0}, hollow}),
    ?assertEqual(6, length(Hollow)),
    %% the centre is on the free side of every container wall
    [?assert(rw_vec:dot(N, {1.0, 0.0, 0.0}) > Off) || {N, Off} <- Hollow],
    ?assert(lists:any(fun(Wall) -> rw_test_lib:bitwise_equal({{-1.0, 0.0, 0.0}, -3.0}, Wall) end, Hollow)),
    Solid = rw_exact:walls({box, {1.0, 0.0, 0.0}, {2.0, 3.0, 4.0}, solid}),
    ?assertEqual(6, length(Solid)),
    %% the centre is on the solid side of every face, a point outside on the free side of one
    [?assert(rw_vec:dot(N, {1.0, 0.0, 0.0}) < Off) || {N, Off, _} <- Solid],
    ?assertEqual(1, length([x || {N, Off, _} <- Solid, rw_vec:dot(N, {4.0, 0.0, 0.0}) > Off])),
    ?assertError({unsupported, cylinder}, rw_exact:walls({cylinder, {0.0, 0.0, 0.0}, {0.0, 1.0, 0.0}, 1.0, 1.0})).

container_keeps_speed_test() ->
    %% a sphere bouncing between the x walls of a 2 m box at 1 m/s: the
    %% centre moves between -0.9 and 0.9, a period of 3.6 s
    W = world(undefined, 1.0, rw_exact:walls({box, {0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}, hollow})),
    {[{800, [{b, {X1, _, _}, {V1, _, _}}]}, {3600, [{b, {X2, _, _}, {V2, _, _}}]}], Events} =
        rw_exact:run(W, [ball(b, 0.1, 1.0, {0.0, 0.0, 0.0}, {1.0, 0.0, 0.0})], [800, 3600]),
    ?assertMatch([{_, {plane, 1, 4}}, {_, {plane, 1, 1}}], Events),
    near(X1, 0.8), near(V1, 1.0),
    ?assert(abs(X2) < 1.0e-12), near(V2, 1.0).

thin_wall_bounces_test() ->
    %% scenarios/fast_thin_wall.json: r = 0.05 at 5000 m/s against a 2 cm wall
    %% whose face is at x = 10.29; it touches at t = 10.24 / 5000 s
    W = world(undefined, 1.0, rw_exact:walls({box, {10.3, 0.0, 0.0}, {0.01, 2.0, 2.0}, solid})),
    {[{10, [{bullet, {X, _, _}, V}]}], [{T, {plane, 1, 1}}]} =
        rw_exact:run(W, [ball(bullet, 0.05, 1.0, {0.0, 0.0, 0.0}, {5000.0, 0.0, 0.0})], [10]),
    near(T, 10.24 / 5000),
    ?assertBitwise({-5000.0, 0.0, 0.0}, V),
    near(X, 10.24 - 5000.0 * (0.010 - 10.24 / 5000)).

beside_a_solid_box_test() ->
    %% passes 1 m beside the wall: no impact
    W = world(undefined, 1.0, rw_exact:walls({box, {10.3, 0.0, 0.0}, {0.01, 2.0, 2.0}, solid})),
    {_, []} = rw_exact:run(W, [ball(b, 0.05, 1.0, {0.0, 3.0, 0.0}, {5000.0, 0.0, 0.0})], [10]).

edge_impacts_are_not_modelled_test() ->
    W = world(undefined, 1.0, rw_exact:walls({box, {10.3, 0.0, 0.0}, {0.01, 2.0, 2.0}, solid})),
    ?assertError({unsupported, {edge_or_corner_impact, b, _}},
                 rw_exact:run(W, [ball(b, 0.05, 1.0, {0.0, 2.02, 0.0}, {5000.0, 0.0, 0.0})], [10])).

lands_on_a_solid_box_test() ->
    %% dropped onto the top face of a box, restitution 0: it stays there
    G = {0.0, -9.81, 0.0},
    W = world(G, 0.0, rw_exact:walls({box, {0.0, -1.0, 0.0}, {2.0, 1.0, 2.0}, solid})),
    {[{2000, [{b, {_, Y, _}, V}]}], [{T, {plane, 1, 4}}]} =
        rw_exact:run(W, [ball(b, 0.5, 1.0, {0.0, 1.5, 0.0}, {0.0, 0.0, 0.0})], [2000]),
    near(T, math:sqrt(2 * 1.0 / 9.81)),
    near(Y, 0.5),
    ?assertBitwise({0.0, 0.0, 0.0}, V).

resting_sphere_slides_test() ->
    %% starts touching the floor of a container, moving sideways at 2 m/s:
    %% it rests on the floor at once, keeps sliding (no friction) and
    %% bounces off the wall at x = 1 after 0.45 s
    G = {0.0, -9.81, 0.0},
    W = world(G, 1.0, rw_exact:walls({box, {0.0, 5.0, 0.0}, {1.0, 5.0, 1.0}, hollow})),
    {[{1000, [{b, {X, Y, _}, {Vx, Vy, _}}]}], Events} =
        rw_exact:run(W, [ball(b, 0.1, 1.0, {0.0, 0.1, 0.0}, {2.0, 0.0, 0.0})], [1000]),
    ?assertMatch([{_, {plane, 1, 2}}, {_, {plane, 1, 4}}], Events),
    ?assertBitwise(0.0, element(1, hd(Events))),
    near(element(1, lists:last(Events)), 0.45),
    ?assertBitwise({0.1, 0.0}, {Y, Vy}),
    ?assertBitwise(-2.0, Vx),
    near(X, 0.9 - 2.0 * (1.0 - 0.45)).

many_frames_agree_with_one_test() ->
    %% frames do not disturb the event sequence (the next impact is kept across frames)
    G = {0.0, -9.81, 0.0},
    W = world(G, 0.9, rw_exact:walls({box, {0.0, 2.0, 0.0}, {2.0, 2.0, 2.0}, hollow})),
    Bodies = [ball(a, 0.2, 1.0, {-1.0, 1.0, 0.0}, {3.0, 2.0, 1.0}), ball(b, 0.3, 2.0, {1.0, 1.5, 0.5}, {-2.0, 0.0, -1.0})],
    {[{3000, One}], E1} = rw_exact:run(W, Bodies, [3000]),
    {Many, E2} = rw_exact:run(W, Bodies, lists:seq(0, 3000, 7) ++ [3000]),
    {3000, Last} = lists:last(Many),
    ?assertEqual(length(E1), length(E2)),
    [?assert(rw_vec:len(rw_vec:sub(P1, P2)) < 1.0e-9) || {{_, P1, _}, {_, P2, _}} <- lists:zip(One, Last)],
    ?assert(length(E1) > 3).
