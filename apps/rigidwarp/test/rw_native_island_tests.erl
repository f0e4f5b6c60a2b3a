%% The C island (rw_native:island_run/10) against the island it stands for,
%% rw_island:step/3: contact groups of touching spheres with every kind of
%% fixture, with and without gravity (each integrator), rotation, friction,
%% slop and rest speed, the same states bit for bit substep by substep; and
%% rw_chain:run/5 for groups the same with the C loops and with the Erlang
%% code alone, with known contacts from outside, from a group's start,
%% across sync points and at awkward doubles, where the Erlang code raises
%% badarith and the C code must hand over to it.
-module(rw_native_island_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").

models() ->
    G = {0.0, -9.81, 0.0},
    [#model{},
     #model{gravity = G},
     #model{gravity = G, integrator = explicit_euler, restitution = 0.3},
     #model{gravity = {0.3, -9.81, 0.1}, integrator = verlet, friction = 0.5},
     #model{gravity = G, rotation = true, friction = 0.6, restitution = 0.2},
     #model{rotation = true, friction = 0.3},
     #model{gravity = G, rotation = true, friction = 0.3, restitution = 0.5, rest_speed = 0.2, slop = 0.001,
            correction = 0.2},
     #model{gravity = G, rotation = true, dt = 1.0e-4, restitution = 0.8}].

sceneries() ->
    Floor = rw_shape:fixture(0, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0}),
    [[],
     [Floor],
     [rw_shape:fixture(0, <<"box">>, {box, {0.0, 0.5, 0.0}, {0.6, 0.6, 0.6}, hollow})],
     [rw_shape:fixture(0, <<"slope">>, {plane, rw_vec:norm({0.2, 1.0, -0.1}), -0.05})],
     [Floor,
      rw_shape:fixture(1, <<"block">>, {box, {0.3, 0.3, 0.0}, {0.2, 0.2, 0.2}, solid}),
      rw_shape:fixture(2, <<"log">>, {cylinder, {-0.3, 0.35, 0.0}, {0.0, 0.0, 1.0}, 0.15, 1.0})],
     [rw_shape:fixture(3, <<"tilted">>, {cylinder, {0.0, 0.2, 0.0}, rw_vec:norm({1.0, 0.3, 0.2}), 0.2, 0.5}),
      rw_shape:fixture(9, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0})]].

%% Substep by substep, the C island's states are the island's, bit for bit
%% (over as many substeps as one call takes: all of them, or fewer where
%% half a time slice is up first).
island_run_equals_island_step_test() ->
    _ = rand:seed(exsss, {2013, 11, 25}),
    Cases = [group_case(M, Fx) || M <- models(), Fx <- sceneries(), _ <- lists:seq(1, 12)],
    Outcomes = [compare_steps(Case) || Case <- Cases],
    ?assertEqual([], [C || {C, false} <- lists:zip(Cases, [Same || {Same, _, _} <- Outcomes])]),
    %% the cases have members touching each other and fixtures
    Pairs = length([x || {_, true, _} <- Outcomes]),
    Fixed = length([x || {_, _, true} <- Outcomes]),
    ?assert(Pairs > length(Cases) div 2),
    ?assert(Fixed > length(Cases) div 4).

compare_steps({T, States, Last, {M, _, _, _, _}, Island}) ->
    {_, Spheres, Fixtures} = rw_island:bodies(Island),
    {T1, Native, Bins, none, []} = rw_native:island_run(T, Last, 1, M, Spheres, Fixtures, States, none, [], []),
    Rot = M#model.rotation,
    {Erlang, ErlangBins} = steps(T1 - T, States, Island, [<<>> || _ <- tuple_to_list(States)], Rot),
    Same = T1 > T andalso T1 =< Last andalso rw_test_lib:bitwise_equal({Native, Bins}, {Erlang, ErlangBins}),
    {Same, pairs_touch(Spheres, States), fixtures_touched(Spheres, States, Fixtures)}.

steps(0, States, _Island, Bins, _Rot) -> {States, Bins};
steps(K, States, Island, Bins, Rot) ->
    {_, Next, Island1} = rw_island:step(Island, States, []),
    steps(K - 1, Next, Island1,
          [rw_states:append(Bin, St, undefined, Rot) || {Bin, St} <- lists:zip(Bins, tuple_to_list(Next))], Rot).

pairs_touch(Spheres, States) ->
    Members = lists:zip(tuple_to_list(Spheres), tuple_to_list(States)),
    lists:any(fun({{#sphere{radius = RA}, #st{p = PA}}, {#sphere{radius = RB}, #st{p = PB}}}) ->
                      rw_narrow:sphere_sphere(PA, RA, PB, RB) =/= none
              end, [{A, B} || A <- Members, B <- Members, A < B]).

fixtures_touched(Spheres, States, Fixtures) ->
    lists:any(fun({#sphere{radius = R}, #st{p = P}}) -> rw_dynamics:touches_fixture(P, R, Fixtures) end,
              lists:zip(tuple_to_list(Spheres), tuple_to_list(States))).

%% Piles of 130 and 300 members on the floor, many at the same x (and at
%% 0.0 and -0.0), some resting, some falling in: groups this large step on
%% a dirty scheduler, their neighbour list swept and pruned as rw_island's
%% is. The C island's substeps are the island's, and rw_chain:run/5 is the
%% same both ways.
large_groups_test_() ->
    {timeout, 120,
     fun() ->
             _ = rand:seed(exsss, {3, 1, 4}),
             M = #model{gravity = {0.0, -9.81, 0.0}, rotation = true, friction = 0.4, restitution = 0.3},
             Floor = rw_shape:fixture(0, <<"floor">>, {plane, {0.0, 1.0, 0.0}, 0.0}),
             [begin
                  Case = pile(M, [Floor], N),
                  ?assertMatch({true, true, true}, compare_steps(Case)),
                  ?assert(same_run(Case))
              end || N <- [130, 300]]
     end}.

pile(M, Fixtures, N) ->
    Spheres = [#sphere{idx = I, id = integer_to_binary(I), radius = 0.1, mass = 1.0, inv_mass = 1.0, inv_inertia = 250.0}
               || I <- lists:seq(1, N)],
    States = list_to_tuple(
               [#st{p = {case I rem 10 of 0 -> -0.0; X -> 0.19 * (X - 5) end, 0.095 + 0.19 * (I div 100) + u(0.0, 0.01),
                         0.19 * ((I div 10) rem 10)},
                    v = {u(-0.1, 0.1), u(-1.0, 0.0), 0.0}, q = rw_quat:identity(), w = {0.0, u(-1.0, 1.0), 0.0}}
                || I <- lists:seq(1, N)]),
    {0, States, 30, {M, 1, none, rw_timeline:new(), rw_sync:new(10, 64, 30, 0)}, rw_island:new(M, Spheres, Fixtures)}.

%% Members at the narrowphase's edges: a centre inside the solid block at
%% its centre along an axis (0.0 and -0.0) or on its face, on a cylinder's
%% axis (no radial direction) and past its caps, two centres at the same
%% point (no normal), a centre on the floor, in a corner of the box.
edge_cases_test() ->
    M = #model{gravity = {0.0, -9.81, 0.0}, rotation = true, friction = 0.3, restitution = 0.5},
    [Floor, Block, Log] = lists:nth(5, sceneries()),
    Box = rw_shape:fixture(4, <<"box">>, {box, {0.0, 0.5, 0.0}, {0.6, 0.6, 0.6}, hollow}),
    Fixtures = [Floor, Block, Log, Box],
    Groups = [[{0.3, 0.3, 0.0}, {0.3, 0.45, 0.1}],
              [{0.3, 0.3, -0.0}, {0.45, 0.3, 0.0}],
              [{-0.0, 0.3, 0.0}, {0.35, 0.3, -0.0}, {0.3, 0.1, 0.05}],
              [{0.5, 0.3, 0.0}, {0.3, 0.5, 0.0}, {0.3, 0.3, 0.2}],
              [{-0.3, 0.35, 0.0}, {-0.3, 0.35, 0.9}, {-0.3, 0.35, -1.05}],
              [{0.1, 0.2, 0.1}, {0.1, 0.2, 0.1}],
              [{0.2, 0.0, 0.2}, {0.2, -0.0, 0.3}],
              [{-0.55, 1.05, 0.55}, {-0.45, 1.0, 0.5}]],
    [?assertMatch({true, _, _}, compare_steps(edge_group(M, Fixtures, Ps))) || Ps <- Groups].

edge_group(M, Fixtures, Positions) ->
    Spheres = [#sphere{idx = 10 + I, id = integer_to_binary(I), radius = 0.1, mass = 1.0, inv_mass = 1.0,
                       inv_inertia = 250.0} || I <- lists:seq(1, length(Positions))],
    States = list_to_tuple([#st{p = P, v = {0.5, -1.0, 0.25}, q = rw_quat:identity(), w = {1.0, 0.0, -2.0}}
                            || P <- Positions]),
    {0, States, 20, {M, 1, none, rw_timeline:new(), rw_sync:new(10, 64, 20, 0)}, rw_island:new(M, Spheres, Fixtures)}.

%% rw_chain:run/5 of a group, with the C island and with the Erlang code
%% alone: the same sync points and states (the island it returns keeps its
%% neighbour lists, which the C island does not update: they decide which
%% pairs are tested, never what a test finds).
chain_runs_the_same_both_ways_test() ->
    _ = rand:seed(exsss, {7, 11, 13}),
    Cases = [group_case(M, Fx) || M <- models(), Fx <- sceneries(), _ <- lists:seq(1, 4)],
    ?assertEqual([], [Case || Case <- Cases, not same_run(Case)]).

same_run(Case) ->
    {Native, Erlang} = rw_test_lib:both_ways(fun() -> run(Case) end),
    rw_test_lib:bitwise_equal(Native, Erlang).

run({T, States, Last, Ctx, Island}) ->
    {Passed, Steps, _Island} = rw_chain:run(T, States, Last, Ctx, Island),
    {Passed, Steps}.

%% Groups at awkward doubles: positions, velocities and spins near overflow,
%% signed zeros and subnormals; the same outcome both ways, results or
%% badarith.
chain_at_awkward_doubles_test() ->
    _ = rand:seed(exsss, {17, 19, 23}),
    Results = [rw_test_lib:both_ways(fun() -> run(Case) end)
               || M <- models(), Fx <- sceneries(), _ <- lists:seq(1, 6), Case <- [awkward(group_case(M, Fx))]],
    [?assert(rw_test_lib:bitwise_equal(Native, Erlang)) || {Native, Erlang} <- Results],
    ?assertEqual([error, ok], lists:usort([element(1, Native) || {Native, _} <- Results])).

awkward({T, States, Last, Ctx, Island}) ->
    K = rand:uniform(tuple_size(States)),
    #st{p = P, v = V, w = W} = St = element(K, States),
    Awkward = case rand:uniform(4) of
                  1 -> St#st{v = rw_test_lib:awkward_vec()};
                  2 -> St#st{p = rw_vec:add(P, {rw_test_lib:awkward_double(), 0.0, 0.0})};
                  3 when W =/= undefined -> St#st{w = rw_test_lib:awkward_vec()};
                  _ -> St#st{v = rw_vec:add(V, {0.0, rw_test_lib:awkward_double(), 0.0})}
              end,
    {T, setelement(K, States, Awkward), Last, Ctx, Island}.

%% A group of 2 to 12 spheres packed close enough that many touch, above
%% the floor and among the fixtures, with a known contact from outside at
%% some substep, perhaps from the group's start, over sync points.
group_case(#model{rotation = Rot} = M, Fixtures) ->
    N = 1 + rand:uniform(11),
    Side = 0.3 * math:pow(N, 1 / 3),
    Centre = {u(-0.4, 0.4), 0.25 + u(0.0, 0.3), u(-0.4, 0.4)},
    Spheres = [begin
                   R = u(0.08, 0.2),
                   Mass = u(0.5, 3.0),
                   #sphere{idx = 10 + 2 * I, id = integer_to_binary(I), radius = R, mass = Mass, inv_mass = 1.0 / Mass,
                           inv_inertia = 1.0 / (0.4 * Mass * R * R)}
               end || I <- lists:seq(1, N)],
    States = list_to_tuple(
               [begin
                    P = rw_vec:add(Centre, {u(-Side, Side) / 2, u(-Side, Side) / 2, u(-Side, Side) / 2}),
                    V = {u(-3.0, 3.0), u(-3.0, 3.0), u(-3.0, 3.0)},
                    case Rot of
                        true -> #st{p = P, v = V, q = rw_quat:norm({{u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0)}, 1.0}),
                                    w = {u(-5.0, 5.0), u(-5.0, 5.0), lists:nth(rand:uniform(2), [0.0, u(-5.0, 5.0)])}};
                        false -> #st{p = P, v = V}
                    end
                end || _ <- Spheres]),
    T = rand:uniform(100),
    Last = T + rand:uniform(64),
    Idxs = [I || #sphere{idx = I} <- Spheres],
    Contacts = case rand:uniform(3) of
                   1 -> [];
                   _ -> [T + rand:uniform(Last - T) - 1]
               end,
    TL = lists:foldl(fun(TC, Acc) ->
                             Member = lists:nth(rand:uniform(N), Idxs),
                             Effect = {{u(-1.0, 1.0), 0.5, 0.0}, case Rot of true -> {0.0, 1.0, 0.0}; false -> undefined end,
                                       {0.0, 0.0, 0.0}},
                             rw_timeline:put_contacts(TC, #{{TC, 3, Member, make_ref()} => {Member, 3, Effect}}, Acc)
                     end, rw_timeline:new(), Contacts),
    Base = case rand:uniform(3) of
               1 -> {T, list_to_tuple([rw_dynamics:respond(St, []) || St <- tuple_to_list(States)])};
               _ -> none
           end,
    Cal = rw_sync:new(10, 64, Last + rand:uniform(2) - 1, lists:nth(rand:uniform(2), [0, 10])),
    {T, States, Last, {M, 1, Base, TL, Cal}, rw_island:new(M, Spheres, Fixtures)}.

u(Lo, Hi) -> Lo + (Hi - Lo) * rand:uniform().
