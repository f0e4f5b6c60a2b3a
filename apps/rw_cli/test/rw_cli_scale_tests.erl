%% The scale bench's arithmetic: how often a gas runs, and how its runs
%% make one figure.
-module(rw_cli_scale_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).

%% Enough runs for 5 million body-substeps, rounded up, at least one and
%% at most 20: every count runs the same simulated time.
runs_test() ->
    [?assertEqual({N, Until, Runs}, {N, Until, rw_cli_scale:runs(N, Until)})
     || {N, Until, Runs} <- [{500, 1000, 10}, {3000, 1000, 2}, {5000, 1000, 1}, {20000, 1000, 1}, {500, 100, 20},
                             {20, 100, 20}]].

%% Runs count as one: body-substeps over their wall times together (not
%% the mean of their rates), once running likewise, the memory of the last.
combine_test() ->
    Run = fun(Wall, RunningMs, RunningSim, Kib) ->
                  #{spheres => 10, simulated_ms => 100, wall_ms => Wall, running_ms => RunningMs,
                    running_sim_ms => RunningSim, kib_per_body => Kib}
          end,
    #{wall_ms := Wall, body_substeps_per_s := Rate, running_per_s := Running, kib_per_body := Kib} =
        rw_cli_scale:combine([Run(100, 70, 80, [1.0, 2.0, 3.0]), Run(300, 250, 80, [4.0, 5.0, 6.0])]),
    ?assertEqual(400, Wall),
    ?assertBitwise(10 * 100 * 2 / 400 * 1000, Rate),
    ?assertBitwise(10 * 160 / 320 * 1000, Running),
    ?assertBitwise([4.0, 5.0, 6.0], Kib).

%% --scenes writes the gases the bench runs as scene files that run to
%% --until (for scripts/ab), prints their paths and runs none; a directory
%% it cannot write is bad input.
scenes_test() ->
    Dir = string:trim(os:cmd("mktemp -d")),
    try
        Out = filename:join(Dir, "gases"),
        ?assertEqual(0, rw_cli_scale:bench(["--counts", "20,60", "--until", "300", "--scenes", Out])),
        [begin
             File = filename:join(Out, "gas_" ++ integer_to_list(N) ++ ".json"),
             {ok, Loaded} = rigidwarp:load(File, #{}),
             {ok, Expected} = rw_scene:from_map(rw_cli_scale:scene(N), #{file => File,
                                                                        overrides => #{duration_ms => 300}}),
             ?assertEqual(Expected, Loaded)
         end || N <- [20, 60]],
        NotADir = filename:join(Dir, "file"),
        ok = file:write_file(NotADir, <<>>),
        ?assertThrow({bad_input, "--scenes: cannot write " ++ _},
                     rw_cli_scale:bench(["--counts", "20", "--scenes", filename:join(NotADir, "gases")]))
    after
        os:cmd("rm -rf '" ++ Dir ++ "'")
    end.
