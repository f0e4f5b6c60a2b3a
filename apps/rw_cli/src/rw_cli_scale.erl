%% `rigidwarp bench scale`: the cost of a body-substep as scenes grow. A
%% family of gases at Bouncing 500's density (2 spheres of radius 0.25 per
%% m^3, speeds up to 4 m/s, restitution 1, a closed box), from 500 spheres
%% up, each run on every scheduler over the same simulated time: body-
%% substeps per second over the whole run and once every body is running
%% (from a fifth of the simulated time on: starting thousands of processes
%% and their first writes is a cost of its own), and the memory per body a
%% quarter, half and three quarters of the way. Every count is measured
%% over the same span of its gas's life, for a gas settles as it runs (its
%% first second runs slower per body-substep than its tenth), so a small
%% gas runs the same simulated time several times over, until its runs
%% have computed ?MIN_WORK body-substeps together (at most ?MOST_RUNS
%% runs): half a second of 500 spheres swings by a quarter with the host,
%% and the 500 is what the others are compared with. With several rounds
%% every count runs once a round, in the opposite order each round, so
%% that the host's drift falls on all alike; each count's rates are the
%% medians of its rounds, and its ratio to the first count the median of
%% the rounds' ratios.
-module(rw_cli_scale).
-export([bench/1, scene/1, runs/2, combine/1]).
-export_type([run/0]).

-define(COUNTS, [500, 2000, 5000, 10000, 20000]).
-define(VALUE_FLAGS, ["--counts", "--until", "--rounds", "--scenes"]).
-define(DENSITY, 2.0).
-define(MIN_WORK, 5000000).
-define(MOST_RUNS, 20).

%% One run: its wall time, the part of it once running and the simulated
%% ms in that part, its memory per body at three points.
-type run() :: #{spheres := pos_integer(), simulated_ms := pos_integer(), wall_ms := non_neg_integer(),
                 running_ms := non_neg_integer(), running_sim_ms := non_neg_integer(), kib_per_body := [float()]}.

-spec bench([string()]) -> 0.
bench(Args) ->
    case parse(Args, #{counts => ?COUNTS, until => 500, rounds => 1}) of
        #{scenes := Dir, counts := Counts, until := Until} -> write_scenes(Dir, Counts, Until);
        Opts -> measure(Opts)
    end.

measure(#{counts := Counts, until := Until, rounds := Rounds}) ->
    io:put_chars(["| spheres | runs | simulated (ms) | wall (ms) | body-substeps/s | once running | vs the first | "
                  "memory per body at 1/4, 1/2, 3/4 (KiB) |\n|---:|---:|---:|---:|---:|---:|---:|---|\n"]),
    %% each round's runs by count
    Runs = [maps:from_list([{N, count(N, Until, Round, Rounds)} || N <- order(Counts, Round)])
            || Round <- lists:seq(1, Rounds)],
    [First | _] = Counts,
    Rows = [row(N, [maps:get(N, R) || R <- Runs], [maps:get(First, R) || R <- Runs]) || N <- Counts],
    io:put_chars([jiffy:encode(#{until_ms => Until, density_per_m3 => ?DENSITY, rounds => Rounds, counts => Rows,
                                 schedulers => erlang:system_info(schedulers)}), $\n]),
    0.

%% The counts in the order of round Round: as given, then backwards.
order(Counts, Round) when Round rem 2 =:= 1 -> Counts;
order(Counts, _Round) -> lists:reverse(Counts).

parse([], O) -> O;
parse(["--counts", V | Rest], O) ->
    Counts = [rw_cli_args:pos_int("--counts", C) || C <- string:split(V, ",", all)],
    case Counts -- lists:usort(Counts) of
        [] -> parse(Rest, O#{counts => Counts});
        [Twice | _] -> throw({usage, "--counts names " ++ integer_to_list(Twice) ++ " twice"})
    end;
parse(["--until", V | Rest], O) -> parse(Rest, O#{until => rw_cli_args:pos_ms("--until", V)});
parse(["--rounds", V | Rest], O) -> parse(Rest, O#{rounds => rw_cli_args:pos_int("--rounds", V)});
parse(["--scenes", Dir | Rest], O) -> parse(Rest, O#{scenes => Dir});
parse([[$- | _] = Flag | _], _) -> rw_cli_args:bad_flag(Flag, ?VALUE_FLAGS);
parse([Extra | _], _) -> throw({usage, "unexpected argument " ++ Extra}).

%% The gases as scene files DIR/gas_N.json that run to Until, for a
%% comparison of two builds on them (scripts/ab runs each round's builds in
%% random order: the host drifts too much for runs in a fixed order); none
%% is run. Their paths, a line each.
write_scenes(Dir, Counts, Until) ->
    Files = [{filename:join(Dir, ["gas_", integer_to_list(N), ".json"]), N} || N <- Counts],
    _ = [begin
             Json = [jiffy:encode((scene(N))#{<<"duration_ms">> => Until}, [pretty]), $\n],
             try ok = rw_cli_report:write_atomically(File, Json)
             catch throw:{bad_input, Msg} -> throw({bad_input, "--scenes: " ++ Msg})
             end,
             io:format("~ts~n", [File])
         end || {File, N} <- Files],
    0.

%% How many runs of Until ms the gas of N makes in a round: enough for
%% ?MIN_WORK body-substeps (1 ms substeps), at least one, at most
%% ?MOST_RUNS.
-spec runs(pos_integer(), pos_integer()) -> pos_integer().
runs(N, Until) -> max(1, min(?MOST_RUNS, (?MIN_WORK + N * Until - 1) div (N * Until))).

%% The gas of N spheres.
-spec scene(pos_integer()) -> map().
scene(N) ->
    H = math:pow(N / ?DENSITY, 1 / 3) / 2,
    #{<<"name">> => iolist_to_binary(["gas_", integer_to_list(N)]), <<"duration_ms">> => 1000, <<"substep_ms">> => 1,
      <<"stride_ms">> => 64, <<"frame_ms">> => 10, <<"model">> => #{<<"restitution">> => 1.0},
      <<"bodies">> => [#{<<"id">> => <<"box">>, <<"shape">> => <<"box">>, <<"static">> => true, <<"hollow">> => true,
                         <<"half_extents">> => [H, H, H], <<"position">> => [0, 0, 0]}],
      <<"generators">> => [#{<<"type">> => <<"random">>, <<"id_prefix">> => <<"s">>, <<"count">> => N,
                             <<"seed">> => 2013, <<"min">> => [-H, -H, -H], <<"max">> => [H, H, H],
                             <<"radius">> => 0.25, <<"mass">> => 1.0, <<"speed">> => 4.0}]}.

%% A round's runs of the gas of N spheres to Until, combined; a line on
%% stderr says so.
count(N, Until, Round, Rounds) ->
    Runs = runs(N, Until),
    #{running_per_s := Running} = C = combine([run(N, Until) || _ <- lists:seq(1, Runs)]),
    io:format(standard_error, "round ~b of ~b: ~b spheres, ~b run~s of ~b ms, ~.3g body-substeps/s once running~n",
              [Round, Rounds, N, Runs, case Runs of 1 -> ""; _ -> "s" end, Until, Running]),
    C#{simulated_ms => Until, runs => Runs}.

%% Runs of the gas of N spheres to Until as one: the rates over their
%% wall times together, the memory of the last.
-spec combine([run()]) -> #{wall_ms := non_neg_integer(), body_substeps_per_s := float(), running_per_s := float(),
                             kib_per_body := [float()]}.
combine(Runs) ->
    Sum = fun(Key) -> lists:sum([maps:get(Key, R) || R <- Runs]) end,
    #{spheres := N, simulated_ms := Until} = hd(Runs),
    Wall = Sum(wall_ms),
    #{wall_ms => Wall, body_substeps_per_s => N * Until * length(Runs) / max(1, Wall) * 1000,
      running_per_s => N * Sum(running_sim_ms) / max(1, Sum(running_ms)) * 1000,
      kib_per_body => maps:get(kib_per_body, lists:last(Runs))}.

%% One run of the gas of N spheres to Until: its wall time (to the run's
%% own word that it is done), the part of it once running, its memory per
%% body.
run(N, Until) ->
    {ok, Scene} = rw_scene:from_map(scene(N), #{overrides => #{duration_ms => Until}}),
    erlang:garbage_collect(),
    Base = erlang:memory(total),
    {ok, {rw_sim, Run, _} = Sim} = rw_timewarp:start(Scene, #{read_frames => false}),
    T0 = erlang:monotonic_time(millisecond),
    {Wall, Samples} = sample(Run, Sim, T0, []),
    ok = rw_timewarp:stop(Sim),
    %% once running: from the first sample past a fifth of the simulated time
    {Ts, Gs} = case [{T, G} || {T, G, _} <- Samples, G >= Until div 5] of
                   [{T1, G1} | _] -> {Wall - T1, Until - G1};
                   [] -> {Wall, Until}
               end,
    PerBody = fun(M) -> (M - Base) / N / 1024 end,
    At = fun(G0) -> case [M || {_, G, M} <- Samples, G >= G0] of [M1 | _] -> PerBody(M1); [] -> 0.0 end end,
    #{spheres => N, simulated_ms => Until, wall_ms => Wall, running_ms => Ts, running_sim_ms => Gs,
      kib_per_body => [At(Until div 4), At(Until div 2), At(3 * Until div 4)]}.

%% The row of N spheres from its runs, one a round, and those of the first
%% count in the same rounds: medians, the median of the rounds' ratios to
%% the first (and their range), the memory of the last round.
row(N, [#{simulated_ms := Until, runs := NRuns} | _] = Runs, FirstRuns) ->
    Median = fun(Key) -> rw_machine:median([maps:get(Key, R) || R <- Runs]) end,
    Wall = round(Median(wall_ms)),
    Rate = Median(body_substeps_per_s),
    Running = Median(running_per_s),
    Ratios = [maps:get(running_per_s, R) / maps:get(running_per_s, F) || {R, F} <- lists:zip(Runs, FirstRuns)],
    Vs = rw_machine:median(Ratios),
    {Min, Max} = {lists:min(Ratios), lists:max(Ratios)},
    [Quarter, Mid, End] = maps:get(kib_per_body, lists:last(Runs)),
    VsText = case Ratios of
                 [_] -> io_lib:format("~.2f", [Vs]);
                 _ -> io_lib:format("~.2f (~.2f-~.2f)", [Vs, Min, Max])
             end,
    io:format("| ~b | ~b | ~b | ~b | ~.3g | ~.3g | ~s | ~.1f / ~.1f / ~.1f |~n",
              [N, NRuns, Until, Wall, Rate, Running, VsText, Quarter, Mid, End]),
    #{spheres => N, runs => NRuns, simulated_ms => Until, wall_ms => Wall, body_substeps_per_s => Rate, running_per_s => Running,
      vs_first => Vs, vs_first_range => [Min, Max], running_per_s_rounds => [maps:get(running_per_s, R) || R <- Runs],
      kib_per_body => [Quarter, Mid, End]}.

%% {Ms since the start, GVT, memory} every 50 ms until the run says it is
%% done, and the ms it took.
sample(Run, Sim, T0, Acc) ->
    receive
        {rw_done, Run, _} -> {erlang:monotonic_time(millisecond) - T0, lists:reverse(Acc)};
        {rw_crashed, Run, Who, Reason} -> error({gas_crashed, Who, Reason})
    after 50 ->
        #{gvt := G} = rw_timewarp:stats(Sim),
        sample(Run, Sim, T0, [{erlang:monotonic_time(millisecond) - T0, max(0, G), erlang:memory(total)} | Acc])
    end.
