%% Contact response with textbook answers.
-module(rw_response_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include("rw_physics.hrl").

-define(TOL, 1.0e-12).
-define(near(A, B), ?assert(abs((A) - (B)) =< ?TOL)).
-define(near(A, B, Tol), ?assert(abs((A) - (B)) =< (Tol))).
-define(near_vec(A, B), ?assert(rw_vec:len(rw_vec:sub(A, B)) =< ?TOL)).

-define(FLOOR, {plane, {0.0, 1.0, 0.0}, 0.0}).

elastic() -> #model{dt = 0.001, restitution = 1.0, rest_speed = 0.0}.

%% Two spheres of radius 0.5 overlapping by 1 cm along x; returns the
%% velocities after the impulse.
head_on(M, MassA, VA, MassB, VB) ->
    {{A, _, _}, {B, _, _}} = head_on_3d(M, MassA, {VA, 0.0, 0.0}, MassB, {VB, 0.0, 0.0}),
    {A, B}.

head_on_3d(M, MassA, VA, MassB, VB) ->
    SA = rw_shape:sphere(0, <<"a">>, 0.5, MassA),
    SB = rw_shape:sphere(1, <<"b">>, 0.5, MassB),
    StA = #st{p = {0.0, 0.0, 0.0}, v = VA},
    StB = #st{p = {0.99, 0.0, 0.0}, v = VB},
    C = rw_narrow:sphere_sphere(StA#st.p, 0.5, StB#st.p, 0.5),
    {{DA, undefined, _}, {DB, undefined, _}} = rw_response:pair(M, SA, StA, SB, StB, C),
    {rw_vec:add(VA, DA), rw_vec:add(VB, DB)}.

%%% Normal impulses

elastic_equal_masses_swap_test() ->
    ?assertBitwise({-2.0, 3.0}, head_on(elastic(), 1.0, 3.0, 1.0, -2.0)),
    ?assertBitwise({0.0, 5.0}, head_on(elastic(), 2.0, 5.0, 2.0, 0.0)).

elastic_unequal_masses_test() ->
    %% v1' = ((m1 - m2) v1 + 2 m2 v2) / (m1 + m2), and symmetrically
    {A, B} = head_on(elastic(), 1.0, 3.0, 3.0, -1.0),
    ?near(-3.0, A),
    ?near(1.0, B),
    {A2, B2} = head_on(elastic(), 2.0, 4.0, 5.0, -3.0),
    ?near(-6.0, A2),
    ?near(1.0, B2).

plastic_test() ->
    %% restitution 0: both leave with the common velocity
    {A, B} = head_on((elastic())#model{restitution = 0.0}, 2.0, 3.0, 1.0, 0.0),
    ?near(2.0, A),
    ?near(2.0, B).

plastic_keeps_tangential_test() ->
    %% only the normal (x) components become equal; y and z are untouched
    {{AX, AY, AZ}, {BX, BY, BZ}} =
        head_on_3d((elastic())#model{restitution = 0.0}, 1.0, {1.0, 2.0, 0.0}, 3.0, {-1.0, 0.0, 3.0}),
    ?near(AX, BX),
    ?near(-0.5, AX),
    ?assertBitwise({2.0, 0.0, 0.0, 3.0}, {AY, AZ, BY, BZ}).

partial_restitution_test() ->
    %% closing at 4, leaving at 0.5 * 4, momentum 2
    {A, B} = head_on((elastic())#model{restitution = 0.5}, 1.0, 3.0, 1.0, -1.0),
    ?near(0.0, A),
    ?near(2.0, B).

oblique_elastic_test() ->
    %% equal masses, B at rest along (0.6, 0.8, 0): B takes A's normal component
    SA = rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
    SB = rw_shape:sphere(1, <<"b">>, 0.5, 1.0),
    StA = #st{p = {0.0, 0.0, 0.0}, v = {1.0, 0.0, 0.0}},
    StB = #st{p = {0.6 * 0.99, 0.8 * 0.99, 0.0}, v = {0.0, 0.0, 0.0}},
    C = rw_narrow:sphere_sphere(StA#st.p, 0.5, StB#st.p, 0.5),
    {{DA, _, _}, {DB, _, _}} = rw_response:pair(elastic(), SA, StA, SB, StB, C),
    ?near_vec({0.64, -0.48, 0.0}, rw_vec:add(StA#st.v, DA)),
    ?near_vec({0.36, 0.48, 0.0}, DB).

separating_pair_gets_no_impulse_test() ->
    ?assertBitwise({-1.0, 1.0}, head_on(elastic(), 1.0, -1.0, 1.0, 1.0)),
    %% sliding past each other without closing
    {{AX, AY, _}, {BX, BY, _}} = head_on_3d(elastic(), 1.0, {0.0, 1.0, 0.0}, 1.0, {0.0, -1.0, 0.0}),
    ?assertBitwise({0.0, 1.0, 0.0, -1.0}, {AX, AY, BX, BY}).

rest_speed_test() ->
    %% approaching slower than rest_speed: no bounce; faster: restitution
    M = (elastic())#model{restitution = 0.8, rest_speed = 0.5},
    S = rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
    Bounce = fun(Vy) ->
                     St = #st{p = {0.0, 0.49, 0.0}, v = {0.0, Vy, 0.0}},
                     [{0, C}] = rw_narrow:sphere_fixture(St#st.p, 0.5, ?FLOOR),
                     {{_, Dvy, _}, _, _} = rw_response:fixture(M, S, St, C),
                     Vy + Dvy
             end,
    ?near(0.0, Bounce(-0.2)),
    ?near(0.0, Bounce(-0.49)),
    ?near(1.6, Bounce(-2.0)),
    ?near(0.8, Bounce(-1.0)),
    ?assertBitwise(0.3, Bounce(0.3)),          % leaving the floor: untouched
    %% between two bodies the relative normal speed counts
    {Slow, _} = head_on(M, 1.0, 0.3, 1.0e12, -0.1),
    ?near(-0.1, Slow, 1.0e-9),
    {Fast, _} = head_on(M, 1.0, 2.0, 1.0e12, 0.0),
    ?near(-1.6, Fast, 1.0e-9).

%%% Friction

floor_contact(M, V, W) ->
    S = rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
    St = #st{p = {0.0, 0.49, 0.0}, v = V, q = case W of undefined -> undefined; _ -> rw_quat:identity() end, w = W},
    [{0, C}] = rw_narrow:sphere_fixture(St#st.p, 0.5, ?FLOOR),
    rw_response:fixture(M, S, St, C).

sliding_friction_spins_forward_test() ->
    %% sliding in +x on a floor (normal +y): friction slows it and spins it
    %% about -z, towards rolling (w = v / r about -z)
    M = #model{dt = 0.001, restitution = 0.0, friction = 0.5, rotation = true},
    {{DVX, DVY, DVZ}, {WX, WY, WZ}, _} = floor_contact(M, {2.0, -1.0, 0.0}, {0.0, 0.0, 0.0}),
    ?near(1.0, DVY),                        % normal velocity removed (restitution 0)
    ?near(-0.5, DVX),                       % mu * normal impulse / m: still sliding
    ?near(0.0, DVZ),
    ?near(0.0, WX),
    ?near(0.0, WY),
    ?near(-2.5, WZ),                        % mu Jn r / I = 0.5 * 0.5 / (0.4 * 0.25)
    ?assert(WZ < 0.0).

sticking_friction_rolls_test() ->
    %% slow sliding: friction stops the contact point; the classic 5/7 rule
    M = #model{dt = 0.001, restitution = 0.0, friction = 0.5, rotation = true},
    {{DVX, _, _}, {_, _, WZ}, _} = floor_contact(M, {0.1, -1.0, 0.0}, {0.0, 0.0, 0.0}),
    VX = 0.1 + DVX,
    ?near(0.1 * 5.0 / 7.0, VX),
    ?near(-VX / 0.5, WZ),                    % rolling: v + w x (0, -r, 0) = 0
    %% already rolling: no friction at all
    {{DVX2, DVY2, _}, {_, _, WZ2}, _} = floor_contact(M, {1.0, -1.0, 0.0}, {0.0, 0.0, -2.0}),
    ?near(0.0, DVX2),
    ?near(1.0, DVY2),
    ?near(0.0, WZ2).

friction_without_rotation_test() ->
    M = #model{dt = 0.001, restitution = 0.0, friction = 0.5, rotation = false},
    {{DVX, DVY, _}, undefined, _} = floor_contact(M, {2.0, -1.0, 0.0}, undefined),
    ?near(-0.5, DVX),
    ?near(1.0, DVY),
    %% slow: stops sliding exactly, never reverses
    {{DVX2, _, _}, undefined, _} = floor_contact(M, {0.3, -1.0, 0.0}, undefined),
    ?near(-0.3, DVX2).

no_friction_when_leaving_test() ->
    M = #model{dt = 0.001, restitution = 0.0, friction = 0.5, rotation = true},
    {Dv, Dw, _} = floor_contact(M, {2.0, 1.0, 0.0}, {0.0, 0.0, 0.0}),
    ?near_vec({0.0, 0.0, 0.0}, Dv),
    ?near_vec({0.0, 0.0, 0.0}, Dw).

pair_friction_spin_test() ->
    %% B closes on A along -x while sliding +y past it. Friction drags A
    %% towards +y and B towards -y; both get spin about +z, and here the
    %% contact points end up stuck together.
    M = #model{dt = 0.001, restitution = 0.0, friction = 0.5, rotation = true},
    S = fun(I) -> rw_shape:sphere(I, integer_to_binary(I), 1.0, 1.0) end,
    StA = #st{p = {0.0, 0.0, 0.0}, v = {0.0, 0.0, 0.0}, q = rw_quat:identity(), w = {0.0, 0.0, 0.0}},
    StB = #st{p = {1.9, 0.0, 0.0}, v = {-1.0, 1.0, 0.0}, q = rw_quat:identity(), w = {0.0, 0.0, 0.0}},
    C = rw_narrow:sphere_sphere(StA#st.p, 1.0, StB#st.p, 1.0),
    {{DvA, DwA, _}, {DvB, DwB, _}} = rw_response:pair(M, S(0), StA, S(1), StB, C),
    ?near_vec({-0.5, 1.0 / 7.0, 0.0}, DvA),
    ?near_vec({0.5, -1.0 / 7.0, 0.0}, DvB),
    ?near_vec({0.0, 0.0, 2.5 / 7.0}, DwA),
    ?near_vec({0.0, 0.0, 2.5 / 7.0}, DwB),
    %% contact points: A's at +x, B's at -x
    VcA = rw_vec:add(DvA, rw_vec:cross(DwA, {1.0, 0.0, 0.0})),
    VcB = rw_vec:add(rw_vec:add(StB#st.v, DvB), rw_vec:cross(DwB, {-1.0, 0.0, 0.0})),
    ?near_vec(VcA, VcB).

%%% Pseudo-velocity (split impulse for penetration)

pseudo_velocity_only_beyond_slop_test() ->
    M = (elastic())#model{slop = 0.01, correction = 0.5},
    S = rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
    Effect = fun(Y) ->
                     St = #st{p = {0.0, Y, 0.0}, v = {0.0, 0.0, 0.0}},
                     [{0, C}] = rw_narrow:sphere_fixture(St#st.p, 0.5, ?FLOOR),
                     rw_response:fixture(M, S, St, C)
             end,
    %% 5 mm deep, slop 1 cm: nothing
    {Dv1, _, Du1} = Effect(0.495),
    ?near_vec({0.0, 0.0, 0.0}, Du1),
    ?near_vec({0.0, 0.0, 0.0}, Dv1),
    %% 5 cm deep: half of the 4 cm beyond slop per substep, as a velocity;
    %% the real velocity is not touched (no energy from penetration)
    {Dv2, _, {UX, UY, UZ}} = Effect(0.45),
    ?near_vec({0.0, 0.0, 0.0}, Dv2),
    ?near(0.0, UX),
    ?near(0.0, UZ),
    ?near(0.5 * 0.04 / 0.001, UY, 1.0e-9).

pair_pseudo_velocity_split_by_mass_test() ->
    M = (elastic())#model{slop = 0.0, correction = 0.4, dt = 0.01},
    SA = rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
    SB = rw_shape:sphere(1, <<"b">>, 0.5, 3.0),
    StA = #st{p = {0.0, 0.0, 0.0}, v = {0.0, 0.0, 0.0}},
    StB = #st{p = {0.9, 0.0, 0.0}, v = {0.0, 0.0, 0.0}},
    C = rw_narrow:sphere_sphere(StA#st.p, 0.5, StB#st.p, 0.5),
    {{_, _, {UA, _, _}}, {_, _, {UB, _, _}}} = rw_response:pair(M, SA, StA, SB, StB, C),
    %% separation speed 0.4 * 0.1 / 0.01 = 4, shared 3 : 1 by inverse mass
    ?near(-3.0, UA, 1.0e-9),
    ?near(1.0, UB, 1.0e-9),
    ?near(4.0, UB - UA, 1.0e-9).

swept_contact_rewinds_new_velocity_test() ->
    %% touching at 0.4 of the substep: the new velocity only acts for the
    %% remaining 0.6, so the pseudo-velocity takes back 0.4 * dv
    M = (elastic())#model{dt = 0.001},
    S = fun(I) -> rw_shape:sphere(I, integer_to_binary(I), 1.0, 1.0) end,
    StA = #st{p = {0.0, 0.0, 0.0}, v = {10000.0, 0.0, 0.0}},
    StB = #st{p = {10.0, 0.0, 0.0}, v = {-10000.0, 0.0, 0.0}},
    C = rw_narrow:swept_sphere_sphere(StA#st.p, {10.0, 0.0, 0.0}, 1.0, StB#st.p, {-10.0, 0.0, 0.0}, 1.0),
    ?assertBitwise(0.4, C#contact.toi),
    {{{DvA, _, _}, _, {DuA, _, _}}, {{DvB, _, _}, _, {DuB, _, _}}} = rw_response:pair(M, S(0), StA, S(1), StB, C),
    ?near(-20000.0, DvA, 1.0e-6),
    ?near(20000.0, DvB, 1.0e-6),
    ?near(8000.0, DuA, 1.0e-6),
    ?near(-8000.0, DuB, 1.0e-6).

no_rotation_no_spin_test() ->
    {{_, DwA, _}, {_, DwB, _}} =
        rw_response:pair(#model{friction = 0.5}, rw_shape:sphere(0, <<"a">>, 0.5, 1.0),
                         #st{p = {0.0, 0.0, 0.0}, v = {1.0, 1.0, 0.0}},
                         rw_shape:sphere(1, <<"b">>, 0.5, 1.0), #st{p = {0.9, 0.0, 0.0}, v = {0.0, 0.0, 0.0}},
                         rw_narrow:sphere_sphere({0.0, 0.0, 0.0}, 0.5, {0.9, 0.0, 0.0}, 0.5)),
    ?assertEqual({undefined, undefined}, {DwA, DwB}).
