%% `rigidwarp bench scale`: the cost of a body-substep as scenes grow. A
%% family of gases at Bouncing 500's density (2 spheres of radius 0.25 per
%% m^3, speeds up to 4 m/s, restitution 1, a closed box), from 500 spheres
%% up, each run on every scheduler for the same simulated time: body-
%% substeps per second over the whole run and once every body is running
%% (from a fifth of the simulated time on: starting thousands of processes
%% and their first writes is a cost of its own), and the memory per body a
%% quarter, half and three quarters of the way. Small gases run longer, so
%% that each run computes at least ?MIN_WORK body-substeps: half a second
%% of 500 spheres swings by a quarter with the host, and the 500 is what
%% the others are compared with.
-module(rw_cli_scale).
-export([bench/1, scene/1]).

-define(COUNTS, [500, 2000, 5000, 10000, 20000]).
-define(VALUE_FLAGS, ["--counts", "--until"]).
-define(DENSITY, 2.0).
-define(MIN_WORK, 5000000).

-spec bench([string()]) -> 0.
bench(Args) ->
    #{counts := Counts, until := Until} = parse(Args, #{counts => ?COUNTS, until => 500}),
    io:put_chars(["| spheres | simulated (ms) | wall (ms) | body-substeps/s | once running | vs the first | "
                  "memory per body at 1/4, 1/2, 3/4 (KiB) |\n|---:|---:|---:|---:|---:|---:|---|\n"]),
    Rows = lists:foldl(fun(N, Acc) -> Acc ++ [row(N, simulated(N, Until), Acc)] end, [], Counts),
    io:put_chars([jiffy:encode(#{until_ms => Until, density_per_m3 => ?DENSITY, counts => Rows,
                                 schedulers => erlang:system_info(schedulers)}), $\n]),
    0.

parse([], O) -> O;
parse(["--counts", V | Rest], O) ->
    Counts = [rw_cli_args:pos_int("--counts", C) || C <- string:split(V, ",", all)],
    parse(Rest, O#{counts => Counts});
parse(["--until", V | Rest], O) -> parse(Rest, O#{until => rw_cli_args:pos_ms("--until", V)});
parse([[$- | _] = Flag | _], _) -> rw_cli_args:bad_flag(Flag, ?VALUE_FLAGS);
parse([Extra | _], _) -> throw({usage, "unexpected argument " ++ Extra}).

%% How long the gas of N runs: Until ms, or long enough for ?MIN_WORK
%% body-substeps (1 ms substeps).
simulated(N, Until) -> max(Until, (?MIN_WORK + N - 1) div N).

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

row(N, Until, Before) ->
    {ok, Scene} = rw_scene:from_map(scene(N), #{overrides => #{duration_ms => Until}}),
    erlang:garbage_collect(),
    Base = erlang:memory(total),
    {ok, Sim} = rw_timewarp:start(Scene, #{}),
    T0 = erlang:monotonic_time(millisecond),
    Samples = sample(Sim, T0, []),
    Wall = erlang:monotonic_time(millisecond) - T0,
    ok = rw_timewarp:stop(Sim),
    %% once running: from the first sample past a fifth of the simulated time
    {Ts, Gs} = case [{T, G} || {T, G, _} <- Samples, G >= Until div 5] of
                   [{T1, G1} | _] -> {Wall - T1, Until - G1};
                   [] -> {Wall, Until}
               end,
    Rate = N * Until / max(1, Wall) * 1000,
    Running = N * Gs / max(1, Ts) * 1000,
    PerBody = fun(M) -> (M - Base) / N / 1024 end,
    At = fun(G0) -> case [M || {_, G, M} <- Samples, G >= G0] of [M1 | _] -> PerBody(M1); [] -> 0.0 end end,
    {Quarter, Mid, End} = {At(Until div 4), At(Until div 2), At(3 * Until div 4)},
    Vs = case Before of [] -> 1.0; [#{running_per_s := R0} | _] -> Running / R0 end,
    io:format("| ~b | ~b | ~b | ~.3g | ~.3g | ~.2f | ~.1f / ~.1f / ~.1f |~n",
              [N, Until, Wall, Rate, Running, Vs, Quarter, Mid, End]),
    #{spheres => N, simulated_ms => Until, wall_ms => Wall, body_substeps_per_s => Rate, running_per_s => Running, vs_first => Vs,
      kib_per_body => [Quarter, Mid, End]}.

%% {Ms since the start, GVT, memory} every 50 ms until the run is done.
sample(Sim, T0, Acc) ->
    case rw_timewarp:stats(Sim) of
        #{status := running, gvt := G} ->
            timer:sleep(50),
            sample(Sim, T0, [{erlang:monotonic_time(millisecond) - T0, max(0, G), erlang:memory(total)} | Acc]);
        _ -> lists:reverse(Acc)
    end.
