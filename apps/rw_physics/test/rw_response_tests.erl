%% Impulses with textbook answers.
-module(rw_response_tests).
-include_lib("eunit/include/eunit.hrl").
-include("rw_physics.hrl").

-define(near(A, B, Tol), ?assert(abs((A) - (B)) < Tol)).

model() -> #model{dt = 0.001, restitution = 1.0, rest_speed = 0.0}.

head_on(M, MassA, VA, MassB, VB) ->
    SA = rw_shape:sphere(0, <<"a">>, 0.5, MassA),
    SB = rw_shape:sphere(1, <<"b">>, 0.5, MassB),
    StA = #st{p = {0.0, 0.0, 0.0}, v = {VA, 0.0, 0.0}},
    StB = #st{p = {0.99, 0.0, 0.0}, v = {VB, 0.0, 0.0}},
    C = rw_narrow:sphere_sphere(StA#st.p, 0.5, StB#st.p, 0.5),
    {{{DA, _, _}, _, _}, {{DB, _, _}, _, _}} = rw_response:pair(M, SA, StA, SB, StB, C),
    {VA + DA, VB + DB}.

elastic_equal_masses_swap_test() ->
    ?assertEqual({-2.0, 3.0}, head_on(model(), 1.0, 3.0, 1.0, -2.0)).

elastic_unequal_masses_test() ->
    {A, B} = head_on(model(), 1.0, 3.0, 3.0, -1.0),
    ?near(-3.0, A, 1.0e-12),
    ?near(1.0, B, 1.0e-12).

plastic_test() ->
    {A, B} = head_on((model())#model{restitution = 0.0}, 2.0, 3.0, 1.0, 0.0),
    ?near(2.0, A, 1.0e-12),
    ?near(2.0, B, 1.0e-12).

separating_pair_gets_no_impulse_test() ->
    ?assertEqual({-1.0, 1.0}, head_on(model(), 1.0, -1.0, 1.0, 1.0)).

rest_speed_test() ->
    M = (model())#model{restitution = 0.8, rest_speed = 0.5},
    {Slow, _} = head_on(M, 1.0, 0.2, 1.0e12, 0.0),
    ?near(0.0, Slow, 1.0e-9),              % below rest speed: no bounce
    {Fast, _} = head_on(M, 1.0, 2.0, 1.0e12, 0.0),
    ?near(-1.6, Fast, 1.0e-9).

rolling_friction_test() ->
    %% a sphere sliding in +x on a floor (normal +y): friction slows it and
    %% spins it about -z (rolling forward)
    M = #model{dt = 0.001, restitution = 0.0, friction = 0.5, rotation = true},
    S = rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
    St = #st{p = {0.0, 0.49, 0.0}, v = {2.0, -1.0, 0.0}, q = rw_quat:identity(), w = {0.0, 0.0, 0.0}},
    [{0, C}] = rw_narrow:sphere_fixture(St#st.p, 0.5, {plane, {0.0, 1.0, 0.0}, 0.0}),
    {{DVX, DVY, _}, {WX, WY, WZ}, _} = rw_response:fixture(M, S, St, C),
    ?near(1.0, DVY, 1.0e-12),               % normal velocity removed
    ?near(-0.5, DVX, 1.0e-12),              % mu * normal impulse / m
    ?assertEqual({0.0, 0.0}, {WX, WY}),
    ?assert(WZ < 0.0).

pseudo_velocity_only_beyond_slop_test() ->
    M = (model())#model{slop = 0.01, correction = 0.5},
    S = rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
    Floor = {plane, {0.0, 1.0, 0.0}, 0.0},
    U = fun(Y) ->
                St = #st{p = {0.0, Y, 0.0}, v = {0.0, 0.0, 0.0}},
                [{0, C}] = rw_narrow:sphere_fixture(St#st.p, 0.5, Floor),
                {_, _, Du} = rw_response:fixture(M, S, St, C),
                Du
        end,
    ?assertEqual({0.0, 0.0, 0.0}, U(0.495)),
    {0.0, Up, 0.0} = U(0.45),
    ?near(0.5 * 0.04 / 0.001, Up, 1.0e-9).
