%% `rigidwarp bench parallelism [SCENE...]`: how far each scene's work
%% could spread over more cores than this machine has. One run on one
%% scheduler records its tasks and their dependencies (rw_trace), and
%% rw_parallelism computes the work, the critical path, the average
%% parallelism and a list schedule's speedup on 2 to 64 cores; then runs
%% without the trace on 1 and 2 schedulers (alternating, medians) give the
%% speedup this machine really has, to check the projection's 2 against.
-module(rw_cli_parallelism).
-export([bench/1]).

-define(CORES, [2, 4, 8, 16, 64]).
-define(DEFAULT_SCENES, ["parallel_200", "parallel_500", "cylinders_200", "cylinders_500", "bouncing_200_100",
                         "bouncing_200_250", "bouncing_200_400", "bouncing_500_250", "pile_300", "heap_500",
                         "stack_1000"]).
-define(VALUE_FLAGS, ["--until", "--repeats"]).

-spec bench([string()]) -> 0.
bench(Args) ->
    #{scenes := Names, until := Until, repeats := Repeats} = parse(Args, #{scenes => [], until => 1000, repeats => 3}),
    Scenes = [load(N, Until) || N <- case Names of [] -> ?DEFAULT_SCENES; _ -> lists:reverse(Names) end],
    io:put_chars(header()),
    Rows = [row(Name, Scene, Repeats) || {Name, Scene} <- Scenes],
    io:put_chars([jiffy:encode(#{machine => machine(), until_ms => Until, repeats => Repeats, scenes => Rows}), $\n]),
    0.

parse([], O) -> O;
parse(["--until", V | Rest], O) -> parse(Rest, O#{until => rw_cli_args:pos_ms("--until", V)});
parse(["--repeats", V | Rest], O) -> parse(Rest, O#{repeats => rw_cli_args:pos_int("--repeats", V)});
parse([[$- | _] = Flag | _], _) -> rw_cli_args:bad_flag(Flag, ?VALUE_FLAGS);
parse([Scene | Rest], #{scenes := S} = O) -> parse(Rest, O#{scenes := [Scene | S]}).

load(Name, Until) ->
    File = rw_cli_scene:resolve(Name),
    case rigidwarp:load(File, #{until => Until}) of
        {ok, Scene} -> {filename:basename(Name, ".json"), Scene};
        {error, Msg} -> throw({bad_input, Msg})
    end.

header() ->
    ["| scene | tasks | work (M reductions) | critical path | parallelism | projected on 2 | 4 | 8 | 16 | 64 | "
     "measured 1 -> 2 | critical path: bodies / buckets / GVT |\n",
     "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n"].

row(Name, Scene, Repeats) ->
    Tab = ets:new(rw_trace, [public, duplicate_bag]),
    try
        {ok, _} = rw_timewarp:run(Scene, #{schedulers => 1, trace => Tab}),
        #{work := Work, critical_path := Path, parallelism := Par, speedup := Speedup, tasks := Tasks,
          critical_by_kind := ByKind} = rw_parallelism:analyze(ets:tab2list(Tab), ?CORES),
        Measured = measured(Scene, Repeats),
        Share = fun(K) -> round(100 * maps:get(K, ByKind, 0.0)) end,
        io:format("| ~ts | ~b | ~.1f | ~.1f % | ~.1f | ~.2f | ~.2f | ~.2f | ~.2f | ~.2f | ~.2f | ~b / ~b / ~b % |~n",
                  [Name, Tasks, Work / 1.0e6, 100 * Path / max(1, Work), Par | [maps:get(P, Speedup) || P <- ?CORES]]
                  ++ [Measured, Share(body), Share(bucket), Share(gvt)]),
        #{scene => list_to_binary(Name), tasks => Tasks, work => Work, critical_path => Path, parallelism => Par,
          projected => maps:from_list([{integer_to_binary(P), S} || {P, S} <- maps:to_list(Speedup)]),
          measured_1_to_2 => Measured,
          critical_by_kind => ByKind}
    after
        ets:delete(Tab)
    end.

%% The median over Repeats alternating pairs of the wall time on one
%% scheduler over that on two.
measured(Scene, Repeats) ->
    Ratios = [begin
                  Order = case R rem 2 of 0 -> [1, 2]; 1 -> [2, 1] end,
                  Walls = maps:from_list([{S, wall(Scene, S)} || S <- Order]),
                  maps:get(1, Walls) / maps:get(2, Walls)
              end || R <- lists:seq(1, Repeats)],
    rw_machine:median(Ratios).

wall(Scene, Schedulers) ->
    {ok, #{wall_ms := Ms}} = rw_timewarp:run(Scene, #{schedulers => Schedulers}),
    max(1, Ms).

machine() ->
    list_to_binary(io_lib:format("~b logical cores, Erlang/OTP ~s", [erlang:system_info(logical_processors),
                                                                     erlang:system_info(otp_release)])).
