%% The pure parts of rw_accuracy: metrics of given frames, the Pareto
%% front, CSV and the table. The sweep itself runs in test/accuracy_SUITE.
-module(rw_accuracy_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include_lib("rigidwarp/include/rigidwarp.hrl").

scene(Spheres, Fixtures, Model) ->
    #scene{name = <<"t">>, duration = 10, substep = 1, stride = 1, frame = 1, model = Model,
           spheres = [rw_shape:sphere(I, Id, R, 1.0) || {I, {Id, R}} <- lists:zip(lists:seq(0, length(Spheres) - 1),
                                                                                 Spheres)],
           initial = [], fixtures = [#fixture{idx = 9, id = <<"f">>, shape = S} || S <- Fixtures], cell_size = 1.0}.

%% Frames of bodies at the given positions (velocities zero), 1 ms apart.
frames(PerFrame) ->
    [{frame, T, [{Id, P, {0.0, 0.0, 0.0}, undefined, undefined} || {Id, P} <- Bodies]}
     || {T, Bodies} <- lists:zip(lists:seq(0, length(PerFrame) - 1), PerFrame)].

%% The exact solution with the same positions (velocities zero).
exact(PerFrame) ->
    {[{T, [{Id, P, {0.0, 0.0, 0.0}} || {Id, P} <- Bodies]}
      || {T, Bodies} <- lists:zip(lists:seq(0, length(PerFrame) - 1), PerFrame)], []}.

crossing_a_wall_is_missed_test() ->
    Wall = {box, {1.0, 0.0, 0.0}, {0.01, 1.0, 1.0}, solid},
    Path = [[{<<"a">>, {0.0, 0.0, 0.0}}], [{<<"a">>, {0.5, 0.0, 0.0}}], [{<<"a">>, {1.5, 0.0, 0.0}}]],
    Scene = scene([{<<"a">>, 0.1}], [Wall], #model{}),
    ?assertBitwise(#{missed => 1, max_penetration => 0.0, pos_err_max => 0.0},
                   maps:with([missed, max_penetration, pos_err_max], rw_accuracy:metrics(Scene, frames(Path), exact(Path)))),
    %% beside the wall: nothing missed
    Beside = [[{<<"a">>, {X, 2.0, 0.0}}] || X <- [0.0, 0.5, 1.5]],
    ?assertMatch(#{missed := 0}, rw_accuracy:metrics(Scene, frames(Beside), exact(Beside))),
    %% into a floor by 0.04 m: seen (penetration), not missed; through it: missed
    Floor = scene([{<<"a">>, 0.1}], [{plane, {0.0, 1.0, 0.0}, 0.0}], #model{}),
    Sink = [[{<<"a">>, {0.0, Y, 0.0}}] || Y <- [0.2, 0.06]],
    #{missed := 0, max_penetration := D} = rw_accuracy:metrics(Floor, frames(Sink), exact(Sink)),
    ?assert(abs(D - 0.04) < 1.0e-12),
    Through = [[{<<"a">>, {0.0, Y, 0.0}}] || Y <- [0.2, -0.01]],
    ?assertMatch(#{missed := 1}, rw_accuracy:metrics(Floor, frames(Through), exact(Through))).

spheres_passing_through_each_other_test() ->
    Scene = scene([{<<"a">>, 0.5}, {<<"b">>, 0.5}], [], #model{}),
    Through = [[{<<"a">>, {-1.0, 0.0, 0.0}}, {<<"b">>, {1.0, 0.0, 0.0}}],
               [{<<"a">>, {0.2, 0.0, 0.0}}, {<<"b">>, {-0.2, 0.0, 0.0}}]],
    #{missed := 1, max_penetration := D} = rw_accuracy:metrics(Scene, frames(Through), exact(Through)),
    ?assert(abs(D - 0.6) < 1.0e-12),
    %% overlapping without passing: penetration only
    Touch = [[{<<"a">>, {-1.0, 0.0, 0.0}}, {<<"b">>, {1.0, 0.0, 0.0}}],
             [{<<"a">>, {-0.45, 0.0, 0.0}}, {<<"b">>, {0.45, 0.0, 0.0}}]],
    ?assertMatch(#{missed := 0}, rw_accuracy:metrics(Scene, frames(Touch), exact(Touch))),
    %% passing side by side, 2 m apart: nothing
    Side = [[{<<"a">>, {-1.0, 0.0, 0.0}}, {<<"b">>, {1.0, 2.0, 0.0}}],
            [{<<"a">>, {1.0, 0.0, 0.0}}, {<<"b">>, {-1.0, 2.0, 0.0}}]],
    ?assertBitwise(#{missed => 0, max_penetration => 0.0},
                   maps:with([missed, max_penetration], rw_accuracy:metrics(Scene, frames(Side), exact(Side)))).

position_error_test() ->
    Scene = scene([{<<"a">>, 0.1}], [], #model{}),
    Path = [[{<<"a">>, {0.0, 0.0, 0.0}}], [{<<"a">>, {1.0, 0.0, 0.0}}]],
    Off = [[{<<"a">>, {0.0, 0.0, 0.0}}], [{<<"a">>, {1.0, 0.3, 0.4}}]],
    #{pos_err_max := Max, pos_err_rms := Rms} = rw_accuracy:metrics(Scene, frames(Off), exact(Path)),
    ?assert(abs(Max - 0.5) < 1.0e-12),
    ?assert(abs(Rms - math:sqrt(0.25 / 2)) < 1.0e-12).

row(Scene, Rt, Err) ->
    #{scene => Scene, substep_ms => 1, stride_ms => 64, integrator => verlet, ccd => false, sim_ms => 1000,
      wall_ms => 1000 / Rt, realtime_factor => Rt, pos_err_max => Err, pos_err_rms => Err / 2,
      energy_drift => 1.0e-3, momentum_drift => undefined, max_penetration => 0.0, missed => 0, impacts => 2}.

pareto_test() ->
    Rows = rw_accuracy:pareto([row(<<"a">>, 10.0, 1.0), row(<<"a">>, 5.0, 0.1), row(<<"a">>, 4.0, 0.5),
                               row(<<"a">>, 10.0, 2.0), row(<<"b">>, 1.0, 5.0)]),
    ?assertEqual([true, true, false, false, true], [P || #{pareto := P} <- Rows]).

csv_test() ->
    Rows = rw_accuracy:pareto([row(<<"a">>, 10.0, 1.0), row(<<"b">>, 2.5, 0.125)]),
    [Header | Lines] = string:split(string:trim(iolist_to_binary(rw_accuracy:csv(Rows))), "\n", all),
    ?assertEqual(<<"scene,substep_ms,stride_ms,integrator,ccd,sim_ms,wall_ms,realtime_factor,pos_err_max,"
                   "pos_err_rms,energy_drift,momentum_drift,max_penetration,missed,impacts,pareto">>, Header),
    ?assertEqual([<<"b,1,64,verlet,0,1000,400.0,2.5,0.125,0.0625,0.001,,0.0,0,2,1">>], tl(Lines)),
    ?assertEqual(length(rw_accuracy:columns()), length(string:split(hd(Lines), ",", all))).

table_test() ->
    Text = iolist_to_binary(rw_accuracy:table(rw_accuracy:pareto([row(<<"a">>, 123.4, 4.567e-3),
                                                                    row(<<"bb">>, 0.5, 12.0)]))),
    [Header, A, <<>>, B] = string:split(string:trim(Text), "\n", all),
    ?assertMatch({match, _}, re:run(Header, "^scene +substep +stride +integrator")),
    ?assertMatch({match, _}, re:run(A, "^a +1 +64 +verlet +off +123 +4.57e-3 .* - .*\\*$")),
    ?assertMatch({match, _}, re:run(B, "^bb +1 +64 +verlet +off +0.500 +12.0 ")),
    %% the columns line up
    ?assertEqual(string:str(binary_to_list(Header), "realtime") + 7,
                 string:str(binary_to_list(A), "123") + 2).

num_test() ->
    ?assertEqual(["0", "-", "123", "12.3", "1.23", "0.123", "0.0123", "1.23e-3", "1.50e5", "-2.50"],
                 [rw_accuracy:num(X) || X <- [0.0, undefined, 123.4, 12.34, 1.234, 0.1234, 0.01234, 0.00123,
                                              150000.0, -2.5]]).
