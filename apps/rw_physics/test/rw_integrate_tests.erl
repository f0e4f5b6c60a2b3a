%% A zero pseudo-velocity or spin, -0.0 in any coordinate included, leaves
%% the velocity and the orientation exactly as they are: no addition of
%% zeros (-0.0 + 0.0 is 0.0) and no renormalisation of the orientation.
-module(rw_integrate_tests).
-include_lib("eunit/include/eunit.hrl").
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include("rw_physics.hrl").

zero_pseudo_velocity_and_spin_change_nothing_test() ->
    %% an orientation not quite of unit length: renormalising it would
    %% change it
    Q = {{0.1, 0.2, 0.3}, 0.9},
    St = #st{p = {-0.0, 0.0, -0.0}, v = {-0.0, 1.0, -0.0}, q = Q, w = {-0.0, 0.0, -0.0}},
    Zeros = [{0.0, 0.0, 0.0}, {-0.0, 0.0, 0.0}, {0.0, -0.0, -0.0}, {-0.0, -0.0, -0.0}],
    [begin
         #st{p = P, q = Q1} = rw_integrate:advance(#model{dt = 0.001, rotation = true}, St, {-0.0, 1.0, -0.0}, Spin, U),
         ?assertBitwise(Q, Q1),
         %% -0.0 + -0.0 * dt: the velocity's -0.0 taken as it is
         ?assertBitwise({-0.0, 0.001, -0.0}, P)
     end || U <- Zeros, Spin <- Zeros],
    %% a spin that is not zero does turn it (and renormalise it)
    #st{q = Turned} = rw_integrate:advance(#model{rotation = true}, St, {0.0, 0.0, 0.0}, {0.0, 1.0e-300, 0.0},
                                           {0.0, 0.0, 0.0}),
    ?assertNotEqual(Q, Turned).
