%% The paper's experiments (Section 6, Figures 7-10) on the machine it runs
%% on. Not part of `make test`: `make bench` runs it and then
%% scripts/plot-bench draws the figures. Every configuration is repeated
%% (BENCH_REPEATS, default 3) and reported as median, min and max; speedups
%% are ratios of runs made in the same repeat. BENCH_MS (default 1000) is
%% the simulated time of each run. Results: doc/bench/*.csv and results.json.
-module(rw_bench_SUITE).
-include_lib("common_test/include/ct.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([fig7_speedup/1, fig8_breakdown/1, fig9_density/1, fig10_stride/1, features/1, contact_vs_isolated/1,
         contact_groups/1, nodes_vs_schedulers/1]).

suite() -> [{timetrap, {hours, 3}}].

all() -> [fig7_speedup, fig8_breakdown, fig9_density, fig10_stride, features, contact_vs_isolated, contact_groups,
          nodes_vs_schedulers].

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    ok = filelib:ensure_dir(filename:join(out_dir(), "x")),
    [{ms, env_int("BENCH_MS", 1000)}, {repeats, env_int("BENCH_REPEATS", 3)} | Config].

end_per_suite(_Config) ->
    _ = erlang:system_flag(schedulers_online, erlang:system_info(schedulers)),
    ok.

%%% Figure 7: speedup against schedulers, over Time Warp on one scheduler
%%% (the paper's measure) and over the sequential reference (the honest one).
fig7_speedup(Config) ->
    Scenes = ["parallel_200", "parallel_500", "cylinders_200", "cylinders_500", "bouncing_200_250",
              "bouncing_500_250"],
    Cores = erlang:system_info(schedulers),
    Rows = lists:append(
             [begin
                  Scene = load(Name, Config),
                  %% with each repeat, the machine's own scaling on plain Erlang work
                  %% (rw_machine): the shared host's capacity drifts, and a speedup
                  %% is read against what the machine gave at the same time
                  Reps = [begin
                              Ref = wall(fun() -> rw_reference:run(Scene, #{}) end, Cores),
                              Tw = [{S, wall(fun() -> rw_timewarp:run(Scene, #{}) end, S)} || S <- lists:seq(1, Cores)],
                              Machine = [{S, rw_machine:parallel_ms(S, Cores)} || S <- lists:seq(1, Cores)],
                              {Ref, Tw, Machine}
                          end || _ <- lists:seq(1, ?config(repeats, Config))],
                  [begin
                       Walls = [proplists:get_value(S, Tw) || {_, Tw, _} <- Reps],
                       OverOne = [proplists:get_value(1, Tw) / proplists:get_value(S, Tw) || {_, Tw, _} <- Reps],
                       OverRef = [Ref / proplists:get_value(S, Tw) || {Ref, Tw, _} <- Reps],
                       MachineOverOne = [proplists:get_value(1, M) / max(1, proplists:get_value(S, M)) || {_, _, M} <- Reps],
                       [Name, S, median([R || {R, _, _} <- Reps])
                        | stats(Walls) ++ stats(OverOne) ++ stats(OverRef) ++ stats(MachineOverOne)]
                   end || S <- lists:seq(1, Cores)]
              end || Name <- Scenes]),
    write_csv("fig7_speedup.csv", ["scene", "schedulers", "reference_ms", "timewarp_ms", "timewarp_min", "timewarp_max",
                                   "speedup_vs_1", "speedup_vs_1_min", "speedup_vs_1_max",
                                   "speedup_vs_reference", "vs_reference_min", "vs_reference_max",
                                   "machine_speedup", "machine_min", "machine_max"], Rows).

%%% Figure 8: where the work goes, counted inside the engine (profile =>
%%% true) in reductions, the VM's own unit of work, which preemption does
%%% not inflate as it does wall time: bucket work (TVHT: probes, writes,
%%% deletes, locks), integration with fixture contacts, rollbacks (the
%%% bodies' side; their deletes are bucket work), GVT work (commits, frames,
%%% pruning), and the rest of the run's reductions (messaging, the state
%%% machines, scheduling of events and acknowledgements).
fig8_breakdown(Config) ->
    Cores = erlang:system_info(schedulers),
    Rows = [begin
                Scene = load(Name, Config),
                {R0, _} = erlang:statistics(exact_reductions),
                {ok, Stats} = with_schedulers(Cores, fun() -> rw_timewarp:run(Scene, #{profile => true}) end),
                {R1, _} = erlang:statistics(exact_reductions),
                Parts = [maps:get(K, Stats) || K <- [tvht_reductions, integrate_reductions, rollback_reductions,
                                                      gvt_reductions]],
                Total = max(R1 - R0, lists:sum(Parts)),
                Rest = Total - lists:sum(Parts),
                [Name | [round(1000 * P / Total) / 10 || P <- Parts ++ [Rest]]]
            end || Name <- ["parallel_200", "cylinders_200", "bouncing_200_250"]],
    write_csv("fig8_breakdown.csv", ["scene", "tvht_pct", "integrate_pct", "rollback_pct", "gvt_pct", "rest_pct"], Rows).

%%% Figure 9: density. Bouncing with 200 spheres in boxes of 100 to 400 m^3.
fig9_density(Config) ->
    Cores = erlang:system_info(schedulers),
    Rows = [begin
                Scene = load(Name, Config),
                Reps = [{wall(fun() -> rw_reference:run(Scene, #{}) end, Cores),
                         wall(fun() -> rw_timewarp:run(Scene, #{}) end, 1),
                         wall(fun() -> rw_timewarp:run(Scene, #{}) end, Cores)}
                        || _ <- lists:seq(1, ?config(repeats, Config))],
                {ok, Stats} = with_schedulers(Cores, fun() -> rw_timewarp:run(Scene, #{}) end),
                [Volume, median([R || {R, _, _} <- Reps]), median([A || {_, A, _} <- Reps])
                 | stats([B || {_, _, B} <- Reps]) ++ [maps:get(rollbacks, Stats), maps:get(efficiency, Stats)]]
            end || {Name, Volume} <- [{"bouncing_200_100", 100}, {"bouncing_200_250", 250},
                                      {"bouncing_200_400", 400}]],
    write_csv("fig9_density.csv", ["volume_m3", "reference_ms", "timewarp_1_ms", "timewarp_ms", "timewarp_min",
                                   "timewarp_max", "rollbacks", "efficiency"], Rows).

%%% Figure 10: runtime against the stride LVT_ub - GVT.
fig10_stride(Config) ->
    Cores = erlang:system_info(schedulers),
    Rows = lists:append(
             [[begin
                   Scene = load(Name, Config, #{stride => Stride}),
                   Walls = [wall(fun() -> rw_timewarp:run(Scene, #{}) end, Cores)
                            || _ <- lists:seq(1, ?config(repeats, Config))],
                   [Name, Stride | stats(Walls)]
               end || Stride <- [16, 32, 64, 128, 256, 512]]
              || Name <- ["parallel_200", "cylinders_200", "bouncing_200_250"]]),
    write_csv("fig10_stride.csv", ["scene", "stride_ms", "timewarp_ms", "timewarp_min", "timewarp_max"], Rows).

%%% A scene pays only for the physics it declares: the same scene with
%%% rotation, friction or gravity switched on, against the scene as
%%% written (which declares none of them). Work is counted in reductions of
%%% the whole run (steady where wall time is noisy) and timed on all cores;
%%% both are reported relative to the scene as written.
features(Config) ->
    Cores = erlang:system_info(schedulers),
    Variants = [{"as_written", #{}},
                {"rotation", #{<<"rotation">> => true}},
                {"friction", #{<<"friction">> => 0.3}},
                {"gravity", #{<<"gravity">> => [0, -9.81, 0]}},
                {"all_three", #{<<"rotation">> => true, <<"friction">> => 0.3, <<"gravity">> => [0, -9.81, 0]}}],
    Rows = lists:append(
             [begin
                  Measured = [begin
                                  Scene = load_with_model(Name, Model, Config),
                                  Runs = [work(Scene, Cores) || _ <- lists:seq(1, ?config(repeats, Config))],
                                  {Variant, median([R || {R, _, _} <- Runs]), [W || {_, W, _} <- Runs]}
                              end || {Variant, Model} <- Variants],
                  {_, BaseReds, BaseWalls} = hd(Measured),
                  [[Name, Variant, Reds, Reds / BaseReds | stats(Walls) ++ [median(Walls) / median(BaseWalls)]]
                   || {Variant, Reds, Walls} <- Measured]
              end || Name <- ["parallel_500", "bouncing_200_250"]]),
    write_csv("features.csv", ["scene", "variant", "reductions", "reductions_vs_as_written", "wall_ms", "wall_min",
                               "wall_max", "wall_vs_as_written"], Rows).

%%% Isolated bodies take long steps and do little work per substep; bodies
%%% in frequent contact take short steps and exchange events. Parallel
%%% (never touching) against Bouncing in its densest box, at a short and a
%%% long stride: per committed body-substep, the reductions, the TVHT
%%% writes (steps) and the events.
contact_vs_isolated(Config) ->
    Cores = erlang:system_info(schedulers),
    Rows = [begin
                {Reds, Wall, Stats} = work(load(Name, Config, #{stride => Stride}), Cores),
                #{committed_substeps := Committed, computed_substeps := Computed, steps := Steps,
                  events := Events, efficiency := Eff} = Stats,
                [Name, Stride, Committed, Reds / Committed, Steps / Committed, Computed / Steps,
                 Events / Committed, Eff, Wall]
            end || Name <- ["parallel_200", "bouncing_200_100"], Stride <- [16, 64, 512]],
    write_csv("contact.csv", ["scene", "stride_ms", "committed_substeps", "reductions_per_substep",
                              "writes_per_substep", "substeps_per_write", "events_per_substep", "efficiency",
                              "wall_ms"], Rows).

%%% Contact groups (beyond the paper): the paper's scenes with bodies in
%%% persistent contact stepped as one entity (the default) and with one
%%% entity per body, as in the paper (groups => false), on all cores:
%%% wall time, the VM's reductions and what the protocol did (TVHT writes,
%%% events, rollbacks, regroups), per repeat.
contact_groups(Config) ->
    Cores = erlang:system_info(schedulers),
    Rows = lists:append(
             [begin
                  Scene = load(Name, Config),
                  [begin
                       Runs = [work(Scene, Cores, Opts) || _ <- lists:seq(1, ?config(repeats, Config))],
                       {_, _, Stats} = hd(Runs),
                       [Name, Mode, median([R || {R, _, _} <- Runs]) | stats([W || {_, W, _} <- Runs])] ++
                           [maps:get(K, Stats) || K <- [steps, events, rollbacks, regroups, efficiency]]
                   end || {Mode, Opts} <- [{"groups", #{}}, {"one_per_body", #{groups => false}}]]
              end || Name <- ["cylinders_200", "cylinders_500", "bouncing_500_250", "parallel_500"]]),
    write_csv("groups.csv", ["scene", "mode", "reductions", "wall_ms", "wall_min", "wall_max", "writes", "events",
                             "rollbacks", "regroups", "efficiency"], Rows).

%%% One simulation over two nodes of one scheduler each (peer nodes on
%%% this machine, talking over loopback TCP) against one node of two
%%% schedulers, in alternating order within each repeat: realtime factors,
%%% their ratio, what crossed between the nodes, and what that predicts
%%% for more machines. The model: the two-node run's extra CPU time over
%%% the one-node run's, divided by its cross-node messages, is a cost per
%%% message (c); on k machines with slabs of space, the bodies' work
%%% divides by k, and the cross-node messages grow with the k-1 borders
%%% between slabs: wall_k = (W + c * M * (k-1)) / k, W the one-node run's
%%% CPU time (2 x its wall), M the two-node run's messages.
nodes_vs_schedulers(Config) ->
    Rows = [begin
                Scene = load(Name, Config),
                Reps = [begin
                            Order = case Rep rem 2 of 0 -> [one, two]; 1 -> [two, one] end,
                            maps:from_list([{Which, on_nodes(Which, Scene)} || Which <- Order])
                        end || Rep <- lists:seq(1, ?config(repeats, Config))],
                One = [R || #{one := R} <- Reps],
                Two = [R || #{two := R} <- Reps],
                Ratios = [maps:get(realtime_factor, T) / maps:get(realtime_factor, O) || #{one := O, two := T} <- Reps],
                SimS = ?config(ms, Config) / 1000,
                Messages = median([maps:get(cross_node_messages, T) || T <- Two]),
                Bytes = median([maps:get(cross_node_bytes, T) || T <- Two]),
                %% CPU ms: two schedulers (or nodes) busy for the wall time
                W1 = 2 * median([maps:get(wall_ms, O) || O <- One]),
                W2 = 2 * median([maps:get(wall_ms, T) || T <- Two]),
                PerMessageUs = max(0.0, (W2 - W1) * 1000 / max(1, Messages)),
                Predict = fun(K) -> SimS * 1000 / ((W1 + PerMessageUs / 1000 * Messages * (K - 1)) / K) end,
                [Name | stats([maps:get(realtime_factor, O) || O <- One]) ++ stats([maps:get(realtime_factor, T) || T <- Two])
                 ++ stats(Ratios)] ++ [Messages / SimS, Bytes / SimS, PerMessageUs, Predict(4), Predict(8), Predict(16)]
            end || Name <- ["parallel_200", "parallel_500", "cylinders_200", "cylinders_500", "bouncing_200_250",
                            "bouncing_500_250"]],
    write_csv("nodes.csv", ["scene", "rtf_1x2", "rtf_1x2_min", "rtf_1x2_max", "rtf_2x1", "rtf_2x1_min", "rtf_2x1_max",
                            "ratio", "ratio_min", "ratio_max", "messages_per_s", "bytes_per_s", "us_per_message",
                            "predicted_rtf_4", "predicted_rtf_8", "predicted_rtf_16"], Rows).

%% One run on one node of two schedulers, or on two nodes of one each.
on_nodes(one, Scene) ->
    {ok, Stats} = rw_timewarp:run(Scene, #{schedulers => 2}),
    Stats;
on_nodes(two, Scene) ->
    {ok, Stats} = rw_timewarp:run(Scene, #{schedulers => 1, nodes => 2}),
    Stats.

%%% Helpers

%% The scene file with its "model" object extended by Model.
load_with_model(Name, Model, Config) ->
    File = filename:join([root(), "scenarios", Name ++ ".json"]),
    {ok, Bin} = file:read_file(File),
    Map = jiffy:decode(Bin, [return_maps]),
    Map1 = Map#{<<"model">> => maps:merge(maps:get(<<"model">>, Map, #{}), Model)},
    {ok, Scene} = rw_scene:from_map(Map1, #{file => File, overrides => #{duration_ms => ?config(ms, Config)}}),
    Scene.

%% Reductions of the whole VM, wall time (ms) and the summary of one Time
%% Warp run on S schedulers.
work(Scene, S) -> work(Scene, S, #{}).

work(Scene, S, Opts) ->
    with_schedulers(S, fun() ->
                               {R0, _} = erlang:statistics(exact_reductions),
                               T0 = erlang:monotonic_time(microsecond),
                               {ok, Stats} = rw_timewarp:run(Scene, Opts),
                               Wall = (erlang:monotonic_time(microsecond) - T0) / 1000,
                               {R1, _} = erlang:statistics(exact_reductions),
                               {R1 - R0, Wall, Stats}
                       end).

load(Name, Config) -> load(Name, Config, #{}).
load(Name, Config, Extra) ->
    File = filename:join([root(), "scenarios", Name ++ ".json"]),
    {ok, Scene} = rigidwarp:load(File, Extra#{until => ?config(ms, Config)}),
    Scene.

%% Wall time (ms) of Run on S schedulers.
wall(Run, S) ->
    with_schedulers(S, fun() ->
                               T0 = erlang:monotonic_time(microsecond),
                               {ok, _} = Run(),
                               (erlang:monotonic_time(microsecond) - T0) / 1000
                       end).

with_schedulers(N, Fun) ->
    Old = erlang:system_flag(schedulers_online, N),
    try Fun() after erlang:system_flag(schedulers_online, Old) end.

median(L) -> lists:nth((length(L) + 1) div 2, lists:sort(L)).
stats(L) -> [median(L), lists:min(L), lists:max(L)].

env_int(Name, Default) ->
    case os:getenv(Name) of
        false -> Default;
        V -> list_to_integer(V)
    end.

%% The repository root: the first directory above this file (rebar3 may run
%% a copy under _build) holding rebar.config and scenarios/.
root() -> root(filename:dirname(filename:absname(?FILE))).
root("/") -> error(no_repo_root);
root(Dir) ->
    case filelib:is_regular(filename:join(Dir, "rebar.config")) andalso
         filelib:is_dir(filename:join(Dir, "scenarios")) of
        true -> Dir;
        false -> root(filename:dirname(Dir))
    end.

out_dir() -> filename:join([root(), "doc", "bench"]).

write_csv(Name, Header, Rows) ->
    Cell = fun(X) when is_float(X) -> io_lib:format("~.4f", [X]);
              (X) when is_integer(X) -> integer_to_list(X);
              (X) -> X
           end,
    Text = [lists:join(",", Header), $\n | [[lists:join(",", [Cell(C) || C <- R]), $\n] || R <- Rows]],
    ok = file:write_file(filename:join(out_dir(), Name), Text),
    ct:log("~s~n~s", [Name, Text]),
    ok.
