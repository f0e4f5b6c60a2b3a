%% The exact event-driven solver against closed forms.
-module(rw_exact_tests).
-include_lib("eunit/include/eunit.hrl").

world(G, E, Planes) -> #{gravity => G, restitution => E, planes => Planes}.
ball(Id, R, M, P, V) -> #{id => Id, r => R, m => M, p => P, v => V}.

near(A, B) -> ?assert(abs(A - B) < 1.0e-12 * max(1.0, abs(A))).

equal_masses_swap_test() ->
    {[{3000, [{a, PA, VA}, {b, PB, VB}]}], [{T, {pair, 1, 2}}]} =
        rw_exact:run(world(undefined, 1.0, []), [ball(a, 0.5, 1.0, {-2.0, 0.0, 0.0}, {1.0, 0.0, 0.0}),
                                                  ball(b, 0.5, 1.0, {2.0, 0.0, 0.0}, {-1.0, 0.0, 0.0})], [3000]),
    near(T, 1.5),
    ?assertEqual({-1.0, 0.0, 0.0}, VA),
    ?assertEqual({1.0, 0.0, 0.0}, VB),
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
    ?assertEqual({0.0, 0.0, 0.0}, V).

cradle_passes_momentum_through_test() ->
    Balls = [ball(list_to_atom([$a + I]), 0.5, 1.0, {float(I), 0.0, 0.0}, {0.0, 0.0, 0.0}) || I <- lists:seq(0, 4)],
    Striker = ball(s, 0.5, 1.0, {-1.5, 0.0, 0.0}, {1.0, 0.0, 0.0}),
    {[{2000, Final}], _} = rw_exact:run(world(undefined, 1.0, []), [Striker | Balls], [2000]),
    Vs = [element(1, V) || {_, _, V} <- Final],
    ?assertEqual([0.0, 0.0, 0.0, 0.0, 0.0, 1.0], Vs).
