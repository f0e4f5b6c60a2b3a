%% Speed versus accuracy (rw_accuracy, `rigidwarp bench accuracy`): small
%% sweeps whose answers are known, the CSV, and the command end to end.
-module(accuracy_SUITE).
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include("rw_test.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([projectile_converges/1, thin_wall_needs_ccd/1, elastic_pair_conserves/1, csv_has_a_row_per_setting/1,
         unsupported_scene/1, command_end_to_end/1]).

suite() -> [{timetrap, {minutes, 2}}].

all() -> [projectile_converges, thin_wall_needs_ccd, elastic_pair_conserves, csv_has_a_row_per_setting,
          unsupported_scene, command_end_to_end].

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    Config.

end_per_suite(_Config) -> ok.

sweep(Scene, Opts) ->
    {ok, Rows} = rw_accuracy:sweep(maps:merge(#{scenes => [rw_test_lib:scenario(Scene)], substeps => [1],
                                                strides => [64], integrators => [symplectic_euler], ccd => [false],
                                                min_runs => 1, min_wall_ms => 0}, Opts)),
    [ct:log("~p", [R]) || R <- Rows],
    Rows.

pick(Rows, Match) ->
    [R] = [R || R <- Rows, maps:with(maps:keys(Match), R) =:= Match],
    R.

%% Symplectic (and explicit) Euler is first order: p(t) is off by g t dt / 2,
%% so the error grows linearly with the substep; velocity Verlet is exact
%% under constant gravity.
projectile_converges(_Config) ->
    Rows = sweep("projectile.json", #{until => 500, substeps => [0.5, 1, 2, 4],
                                      integrators => [symplectic_euler, verlet, explicit_euler]}),
    ?assertEqual(12, length(Rows)),
    Err = fun(I, S) -> maps:get(pos_err_max, pick(Rows, #{integrator => I, substep_ms => S})) end,
    [begin
         ?assert(Err(I, 0.5) < Err(I, 1)),
         ?assert(Err(I, 1) < Err(I, 2)),
         ?assert(Err(I, 2) < Err(I, 4)),
         %% g t dt / 2 at t = 0.5 s
         ?assert(abs(Err(I, 1) - 9.81 * 0.5 * 0.001 / 2) < 1.0e-3 * Err(I, 1)),
         ?assert(abs(Err(I, 4) / Err(I, 1) - 4.0) < 0.01),
         ?assert(abs(Err(I, 1) / Err(I, 0.5) - 2.0) < 0.01)
     end || I <- [symplectic_euler, explicit_euler]],
    [?assert(Err(verlet, S) < 1.0e-12) || S <- [0.5, 1, 2, 4]],
    [?assertBitwise(#{missed => 0, impacts => 0, max_penetration => 0.0},
                    maps:with([missed, impacts, max_penetration], R)) || R <- Rows],
    [?assert(M < 1.0e-12) || #{momentum_drift := M} <- Rows].

%% 5000 m/s against a 2 cm wall: without CCD the bullet goes through (one
%% missed collision), with CCD it bounces back exactly as the exact solver says.
thin_wall_needs_ccd(_Config) ->
    Rows = sweep("fast_thin_wall.json", #{substeps => [1, 4], ccd => [false, true]}),
    ?assertEqual(4, length(Rows)),
    [?assertMatch(#{missed := 1, impacts := 1}, pick(Rows, #{ccd => false, substep_ms => S})) || S <- [1, 4]],
    [begin
         #{missed := 0, impacts := 1, pos_err_max := E} = pick(Rows, #{ccd => true, substep_ms => S}),
         ?assert(E < 1.0e-9)
     end || S <- [1, 4]],
    ?assert(maps:get(pos_err_max, pick(Rows, #{ccd => false, substep_ms => 1})) > 10.0).

%% Restitution 1, no gravity: energy and momentum are kept to rounding at
%% every substep, with and without CCD.
elastic_pair_conserves(_Config) ->
    Rows = sweep("head_on_elastic.json", #{substeps => [1, 16], ccd => [false, true]}),
    ?assertEqual(4, length(Rows)),
    %% (matched inside, not in the generator, which would skip a row that
    %% missed its impact instead of failing)
    [begin
         #{energy_drift := E, momentum_drift := M, missed := 0, impacts := 1} = Row,
         ?assert(E < 1.0e-12),
         ?assert(M < 1.0e-12)
     end || Row <- Rows],
    %% without CCD the pair overlaps by up to the closing distance per substep
    #{max_penetration := D} = pick(Rows, #{ccd => false, substep_ms => 16}),
    ?assert(D > 0.0 andalso D =< 6.0 * 0.016 + 1.0e-9).

csv_has_a_row_per_setting(_Config) ->
    Rows = sweep("head_on_elastic.json", #{until => 100, substeps => [1, 2, 4], strides => [4, 8], ccd => [false, true],
                                           integrators => [verlet, symplectic_euler]}),
    %% no gravity: one integrator; strides rounded up to the substep (4 and 8 at 4 ms)
    ?assertEqual(3 * 2 * 2, length(Rows)),
    ?assertEqual([verlet], lists:usort([I || #{integrator := I} <- Rows])),
    [Header | Lines] = string:split(string:trim(iolist_to_binary(rw_accuracy:csv(Rows))), "\n", all),
    ?assertEqual(iolist_to_binary(lists:join(",", [atom_to_list(C) || C <- rw_accuracy:columns()])), Header),
    ?assertEqual(length(Rows), length(Lines)),
    [?assertMatch(<<"head_on_elastic,", _/binary>>, L) || L <- Lines],
    %% stride changes the speed only
    [First | Others] = [maps:without([stride_ms, wall_ms, realtime_factor, pareto], R)
                        || #{substep_ms := 2, ccd := true} = R <- Rows],
    ?assertEqual(1, length(Others)),
    [?assertBitwise(First, Other) || Other <- Others],
    ?assert(lists:any(fun(#{pareto := P}) -> P end, Rows)).

unsupported_scene(_Config) ->
    {error, Msg} = rw_accuracy:sweep(#{scenes => [rw_test_lib:scenario("cylinders_200.json")], substeps => [1],
                                       strides => [64], integrators => [verlet], ccd => [false]}),
    ?assertMatch({match, _}, re:run(Msg, "cylinders_200: the exact solver")),
    {error, Msg2} = rw_accuracy:sweep(#{scenes => ["/nonexistent.json"], substeps => [1], strides => [64],
                                        integrators => [verlet], ccd => [false]}),
    ?assertMatch({match, _}, re:run(Msg2, "cannot read file")).

%% The escript: a table on stdout, the CSV and the PNG.
command_end_to_end(Config) ->
    Dir = ?config(priv_dir, Config),
    Csv = filename:join(Dir, "sub/acc.csv"),
    Png = filename:join(Dir, "sub/acc.png"),
    {0, Out, Err} = rw_test_lib:run_escript(["bench", "accuracy", "--scenes", "head_on_elastic:200,projectile:100",
                                             "--substeps", "2,4", "--strides", "8", "--ccd", "off",
                                             "--integrators", "verlet", "--out", Csv, "--plot", Png]),
    ct:log("~s~n~s", [Out, Err]),
    [Header | Table] = [L || L <- string:split(string:trim(Out), "\n", all), L =/= <<>>],
    ?assertMatch({match, _}, re:run(Header, "^scene +substep +stride +integrator +ccd +realtime +pos err max")),
    ?assertEqual(4, length(Table)),
    ?assertMatch({match, _}, re:run(Err, "\\[4\\] projectile substep 4 ms stride 8 ms verlet ccd off")),
    {ok, CsvBin} = file:read_file(Csv),
    ?assertEqual(5, length(string:split(string:trim(CsvBin), "\n", all))),
    {ok, <<137, "PNG", _/binary>> = PngBin} = file:read_file(Png),
    ?assert(byte_size(PngBin) > 10000),
    ?assertNot(filelib:is_file(Csv ++ ".part")).
