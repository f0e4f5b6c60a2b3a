%% rw_chain:run/5 steps a body on its own through a fast path while it
%% flies free; rw_chain:run_each/5 steps it substep by substep through its
%% island. Both must give the same states, sync points and island, bit for
%% bit: in free flight with and without gravity (each integrator) and
%% rotation, bouncing on a floor and in a box mid-step, with a known
%% contact with the outside, from a group's start, across sync points;
%% the fast path with its C loop (rw_native) and with the Erlang code alone.
-module(rw_chain_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").

-define(CASES, 60).

models() ->
    [#model{},
     #model{gravity = {0.0, -9.81, 0.0}},
     #model{gravity = {0.0, -9.81, 0.0}, integrator = explicit_euler},
     #model{gravity = {0.3, -9.81, 0.1}, integrator = verlet},
     #model{gravity = {0.0, -9.81, 0.0}, rotation = true, friction = 0.6, restitution = 0.2},
     #model{rotation = true, friction = 0.3}].

sceneries() ->
    [[],
     [rw_shape:fixture(0, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0})],
     [rw_shape:fixture(0, <<"box">>, {box, {0.0, 0.0, 0.0}, {1.5, 1.5, 1.5}, hollow})],
     %% a tilted floor, and shapes whose test the C loop leaves to the
     %% Erlang code beside ones it takes
     [rw_shape:fixture(0, <<"slope">>, {plane, rw_vec:norm({0.2, 1.0, -0.1}), -0.05})],
     [rw_shape:fixture(0, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0}),
      rw_shape:fixture(1, <<"block">>, {box, {0.4, 0.3, 0.0}, {0.2, 0.2, 0.2}, solid}),
      rw_shape:fixture(2, <<"log">>, {cylinder, {-0.5, 0.35, 0.0}, {0.0, 0.0, 1.0}, 0.15, 1.0})],
     [rw_shape:fixture(0, <<"box">>, {box, {0.0, 0.0, 0.0}, {1.5, 1.5, 1.5}, hollow}),
      rw_shape:fixture(1, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0})]].

fast_path_equals_each_substep_test_() ->
    rand:seed(exsss, 2013),
    [{lists:flatten(io_lib:format("model ~b, scenery ~b, case ~b", [Mi, Fi, C])),
      ?_assert(same(Case))}
     || {Mi, M} <- lists:enumerate(models()), {Fi, Fx} <- lists:enumerate(sceneries()), C <- lists:seq(1, ?CASES div 6),
        Case <- [a_case(M, Fx)]].

%% (the fast path with its C loops, rw_native, and with the Erlang code
%% alone; the C island, which steps a body touching a fixture, leaves the
%% island's lists as they were: they decide which fixtures are tested,
%% never what a test finds)
same({T, St, Last, Ctx, Island}) ->
    {FastPassed, FastSteps, _} = rw_chain:run(T, {St}, Last, Ctx, Island),
    ok = rw_native:use(false),
    FastErlang = try rw_chain:run(T, {St}, Last, Ctx, Island) after ok = rw_native:use(true) end,
    {EachPassed, EachSteps, _} = Each = rw_chain:run_each(T, St, Last, Ctx, Island),
    rw_test_lib:bitwise_equal({FastPassed, FastSteps}, {EachPassed, EachSteps}) andalso
        rw_test_lib:bitwise_equal(FastErlang, Each).

%% A sphere gliding along a wall of its box or along the floor, close
%% enough to be out of its free zone for the whole step, touching the wall
%% or the floor now and then (the fast path must also take the substeps at
%% which it is near and touches nothing, and only those).
gliding_along_a_wall_test_() ->
    Box = [rw_shape:fixture(0, <<"box">>, {box, {0.0, 0.0, 0.0}, {1.5, 1.5, 1.5}, hollow})],
    Floor = [rw_shape:fixture(0, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0})],
    [?_assert(same(gliding(M, Fx, Gap, Drift)))
     || M <- [#model{}, #model{gravity = {0.0, -9.81, 0.0}}, #model{rotation = true, friction = 0.3}],
        Fx <- [Box, Floor], Gap <- [1.0e-3, 0.02, 0.2], Drift <- [0.0, 0.05, -0.05]].

gliding(#model{rotation = Rot} = M, [#fixture{shape = Shape}] = Fixtures, Gap, Drift) ->
    R = 0.25,
    Sphere = #sphere{idx = 7, id = <<"s">>, radius = R, mass = 1.0, inv_mass = 1.0, inv_inertia = 1.0 / (0.4 * R * R)},
    %% the box's wall at x = 1.5, or the floor at y = 0
    {P, V} = case Shape of
                 {box, _, _, _} -> {{1.5 - R - Gap, 0.1, -1.0}, {Drift, 0.3, 1.7}};
                 {plane, _, _} -> {{-1.0, R + Gap, 0.3}, {1.7, Drift, -0.2}}
             end,
    St = case Rot of
             true -> #st{p = P, v = V, q = rw_quat:identity(), w = {0.0, 0.0, 2.0}};
             false -> #st{p = P, v = V}
         end,
    Cal = rw_sync:new(10, 64, 200, 0),
    Island0 = rw_island:new(M, [Sphere], Fixtures),
    {_, _, Island} = rw_chain:run_each(3, St, 4, {M, 1, none, rw_timeline:new(), Cal}, Island0),
    {3, St, 130, {M, 1, none, rw_timeline:new(), Cal}, Island}.

%% A sphere near the floor or a wall, falling or flying towards it fast
%% enough to touch it within the step, perhaps with a known contact with
%% another body at some substep and from a group's start.
a_case(#model{rotation = Rot} = M, Fixtures) ->
    R = 0.1 + 0.2 * rand:uniform(),
    Sphere = #sphere{idx = 7, id = <<"s">>, radius = R, mass = 1.0, inv_mass = 1.0,
                     inv_inertia = 1.0 / (0.4 * R * R)},
    P = {u(-1.0, 1.0), R + u(0.0, 0.3), u(-1.0, 1.0)},
    V = {u(-8.0, 8.0), u(-8.0, 8.0), u(-8.0, 8.0)},
    St = case Rot of
             true -> #st{p = P, v = V, q = rw_quat:identity(), w = {u(-5.0, 5.0), u(-5.0, 5.0), 0.0}};
             false -> #st{p = P, v = V}
         end,
    T = rand:uniform(100),
    Last = T + rand:uniform(64),
    Contacts = case rand:uniform(3) of
                   1 -> [];
                   _ -> [T + rand:uniform(Last - T) - 1]
               end,
    TL = lists:foldl(fun(TC, Acc) ->
                             Effect = {{u(-1.0, 1.0), 0.5, 0.0}, case Rot of true -> {0.0, 1.0, 0.0}; false -> undefined end,
                                       {0.0, 0.0, 0.0}},
                             rw_timeline:put_contacts(TC, #{{TC, 3, 7, make_ref()} => {7, 3, Effect}}, Acc)
                     end, rw_timeline:new(), Contacts),
    Base = case rand:uniform(3) of
               1 -> {T, {rw_dynamics:respond(St, [])}};
               _ -> none
           end,
    Cal = rw_sync:new(10, 64, Last + rand:uniform(2) - 1, lists:nth(rand:uniform(2), [0, 10])),
    Island0 = rw_island:new(M, [Sphere], Fixtures),
    %% an island that has stepped before, with its fixtures listed
    {_, _, Island} = rw_chain:run_each(T, St, T + 1, {M, 1, none, rw_timeline:new(), Cal}, Island0),
    {T, St, Last, {M, 1, Base, TL, Cal}, lists:nth(rand:uniform(2), [Island0, Island])}.

u(Lo, Hi) -> Lo + (Hi - Lo) * rand:uniform().
