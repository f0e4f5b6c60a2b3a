%% A sphere's fixture contacts within one substep, with textbook answers:
%% with CCD, what its path meets after a bounce.
-module(rw_dynamics_tests).
-include_lib("eunit/include/eunit.hrl").
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include("rw_physics.hrl").

-define(TOL, 1.0e-12).

elastic_ccd() -> #model{dt = 0.001, restitution = 1.0, rest_speed = 0.0, ccd = true}.

%% One substep: the post-response velocity and the next position.
substep(M, Sphere, St, Fixtures) ->
    Effects = rw_dynamics:fixture_effects(M, Sphere, St, Fixtures),
    {V, W, U} = rw_dynamics:respond(St, [E || {_, E} <- Effects]),
    #st{p = P} = rw_integrate:advance(M, St, V, W, U),
    {Effects, V, P}.

near(A, B) -> rw_vec:len(rw_vec:sub(A, B)) =< ?TOL.

%% A slot 5 cm wide between two walls, a sphere of radius 1 cm across it at
%% 100 m/s: 10 cm per substep, where its centre has 3 cm of room. From the
%% middle it meets the far wall at 0.15 of the substep, the near one at
%% 0.45, the far one at 0.75, and is 1.5 cm from the near wall at the end,
%% flying back: three impacts, each swept after the one before. The first
%% alone would leave it 2.5 cm behind the near wall.
slot_bounces_three_times_in_one_substep_test() ->
    Near = rw_shape:fixture(1, <<"near">>, {plane, {1.0, 0.0, 0.0}, 0.0}),
    Far = rw_shape:fixture(2, <<"far">>, {plane, {-1.0, 0.0, 0.0}, -0.05}),
    Sphere = rw_shape:sphere(0, <<"s">>, 0.01, 1.0),
    St = #st{p = {0.025, 0.0, 0.0}, v = {100.0, 3.0, 0.0}},
    {Effects, V, P} = substep(elastic_ccd(), Sphere, St, [Near, Far]),
    ?assertEqual([{1, 0}, {2, 0}, {2, {0, 3}}], [K || {K, _} <- Effects]),
    ?assertBitwise({-100.0, 3.0, 0.0}, V),
    ?assert(near({0.015, 0.003, 0.0}, P)).

%% Into a corner of a hollow box at the same time on all three axes: it
%% meets one wall first (the lowest feature), then the two it touches at
%% the point of that impact and still approaches, and leaves along the
%% reversed diagonal.
corner_on_three_axes_at_once_test() ->
    Box = rw_shape:fixture(1, <<"box">>, {box, {0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}, hollow}),
    Sphere = rw_shape:sphere(0, <<"s">>, 0.1, 1.0),
    St = #st{p = {0.8, 0.8, 0.8}, v = {200.0, 200.0, 200.0}},
    {Effects, V, P} = substep(elastic_ccd(), Sphere, St, [Box]),
    ?assertEqual([{1, 1}, {1, 3}, {1, 5}], [K || {K, _} <- Effects]),
    ?assertBitwise({-200.0, -200.0, -200.0}, V),
    %% 0.1 m to the corner, 0.1 m back
    ?assert(near({0.8, 0.8, 0.8}, P)).

%% Across a hollow box of 2 m at 14 km/s (14 m a substep), where its
%% centre has 1.8 m of room: eight impacts on the way, and it ends inside,
%% where the unfolded path says: 15 m from the lower end of its room, less
%% eight widths of it, is 0.6 m from that end (x = -0.3), flying on in the
%% direction it started (an even count of bounces).
across_a_small_container_test() ->
    Box = rw_shape:fixture(1, <<"box">>, {box, {0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}, hollow}),
    Sphere = rw_shape:sphere(0, <<"s">>, 0.1, 1.0),
    St = #st{p = {0.1, 0.0, 0.0}, v = {14000.0, 0.0, 0.0}},
    {Effects, V, P} = substep(elastic_ccd(), Sphere, St, [Box]),
    ?assertEqual(8, length(Effects)),
    ?assertBitwise({14000.0, 0.0, 0.0}, V),
    ?assert(abs(element(1, P) + 0.3) =< 1.0e-9),
    ?assertBitwise({0.0, 0.0}, {element(2, P), element(3, P)}).

%% Resting on a floor with CCD (approaching slower than the rest speed, the
%% scenes' default 2 g dt: no bounce): one contact, the one it touches, and
%% no other: the impulse cancels the substep's gravity (the post-response
%% velocity is -g dt, which gravity takes back), so its path goes nowhere.
resting_meets_the_floor_once_test() ->
    M = (elastic_ccd())#model{gravity = {0.0, -9.81, 0.0}, restitution = 0.5, rest_speed = 2 * 9.81 * 0.001},
    Floor = rw_shape:fixture(1, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0}),
    Sphere = rw_shape:sphere(0, <<"s">>, 0.5, 1.0),
    St = #st{p = {0.0, 0.5, 0.0}, v = {0.0, 0.0, 0.0}},
    {Effects, V, _P} = substep(M, Sphere, St, [Floor]),
    ?assertEqual([{1, 0}], [K || {K, _} <- Effects]),
    ?assert(abs(element(2, V) - 9.81 * 0.001) =< ?TOL),
    ?assertBitwise({0.0, 0.0}, {element(1, V), element(3, V)}).
