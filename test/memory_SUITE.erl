%% Memory held to account: every input the validation accepts runs within a
%% memory budget or is refused at once. Each run is the rigidwarp escript
%% as a user runs it, in an OS process of its own, its peak resident size
%% measured (the getrusage high-water mark, through /usr/bin/time) and the
%% process killed when it passes the ceiling, so that a run that grows
%% without bound fails its case instead of exhausting the machine.
%%
%% - frames_do_not_queue: a run writing frames faster than the engine could
%%   hand them over uses about the memory of the same run without frames;
%% - reproducers: the inputs that grew without bound (a tiny substep under
%%   a long stride, a huge stride, a fast sphere with CCD, tiny cells and
%%   radii, a pool of buckets past the process limit, an empty frames path)
%%   each run under the budget or are refused with exit 2 in seconds;
%% - edge_scenes_stay_bounded: a property over scenes at the edges of what
%%   validation accepts (speeds, radii, cell sizes, substeps, strides,
%%   counts, gravity, CCD, both engines).
-module(memory_SUITE).
-include_lib("proper/include/proper.hrl").
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([frames_do_not_queue/1, reproducers/1, edge_scenes_stay_bounded/1]).

%% What a run may use at its peak, and where it is killed (a little above,
%% so that a run over the budget is measured over it, not cut at it).
-define(BUDGET_MB, 2048).
-define(CEILING_MB, 2600).
%% A refusal comes within this much wall time.
-define(REFUSAL_S, 10).

suite() -> [{timetrap, {minutes, 12}}].

all() -> [frames_do_not_queue, reproducers, edge_scenes_stay_bounded].

init_per_suite(Config) ->
    case filelib:is_regular("/usr/bin/time") of
        true -> Config;
        false -> ct:fail("/usr/bin/time is missing (Debian package time; make deps installs it)")
    end.

end_per_suite(_Config) -> ok.

%%% Cases

%% A frame every substep, 200 spheres: the file writer is slower than the
%% engine, which before backpressure queued the frames in the writer's
%% mailbox (peaks of 436 MB over 1.5 simulated seconds and 912 MB over 4,
%% against 120 MB without frames). Its memory must not grow with the
%% run's length, and stay near that of the run without frames.
frames_do_not_queue(Config) ->
    Dir = ?config(priv_dir, Config),
    Scene = rw_test_lib:scenario("bouncing_200_250.json"),
    Run = fun(Until, Frames) -> measured(["run", Scene, "--until", Until, "--frame-ms", "1", "--quiet" | Frames], 180) end,
    File = ["--frames", filename:join(Dir, "frames.jsonl")],
    Without = Run("4000", []),
    Short = Run("1000", File),
    Long = Run("4000", File),
    ct:pal("peak without frames ~b MB; with frames over 1 s ~b MB, over 4 s ~b MB",
           [peak_mb(Without), peak_mb(Short), peak_mb(Long)]),
    [?assertMatch(#{exit := 0}, R) || R <- [Without, Short, Long]],
    ?assert(peak_mb(Long) =< peak_mb(Short) + 64),
    ?assert(peak_mb(Long) =< peak_mb(Without) + 200).

reproducers(Config) ->
    Dir = ?config(priv_dir, Config),
    Box = box(20.0),
    Cases =
        [{"a 1 us substep under a 64 ms stride",
          ["run", rw_test_lib:scenario("stack_1000.json"), "--until", "30", "--substep", "0.001", "--quiet"], 30},
         {"a stride of 100 s",
          ["run", rw_test_lib:scenario("bouncing_500_250.json"), "--until", "3000", "--stride", "100000", "--quiet"], 30},
         {"a sphere at 1e8 m/s with CCD, reference",
          ["run", scene_file(Dir, "fast_ref", fast_sphere(1.0e8, [])), "--engine", "reference", "--quiet"], 30},
         {"a sphere at 1e8 m/s with CCD, Time Warp",
          ["run", scene_file(Dir, "fast_tw", fast_sphere(1.0e8, [])), "--quiet"], 30},
         {"a sphere at 1e12 m/s with CCD in a box",
          ["run", scene_file(Dir, "fast_box", fast_sphere(1.0e12, [Box])), "--quiet"], 30},
         {"a sphere at 1e12 m/s with CCD in a box, reference",
          ["run", scene_file(Dir, "fast_box_ref", fast_sphere(1.0e12, [Box])), "--engine", "reference", "--quiet"], 30},
         {"cells of 1 mm for a 0.5 m sphere",
          ["validate", scene_file(Dir, "tiny_cells", (one_sphere(0.5, 1.0, #{}))#{<<"cell_size">> => 1.0e-3})], 30},
         {"a radius of 1e-100 with CCD",
          ["run", scene_file(Dir, "tiny_radius", one_sphere(1.0e-100, 1.0, #{<<"ccd">> => true})), "--quiet"], 30},
         {"a radius of 1e-300",
          ["run", scene_file(Dir, "tinier_radius", one_sphere(1.0e-300, 1.0, #{})), "--quiet"], 30},
         {"300,000 buckets",
          ["run", rw_test_lib:scenario("bouncing_200_250.json"), "--until", "100", "--buckets", "300000", "--quiet"], 30},
         {"an empty frames path",
          ["run", rw_test_lib:scenario("bouncing_200_250.json"), "--until", "100", "--frames", "", "--quiet"], 30}],
    Results = [{What, measured(Args, Wall)} || {What, Args, Wall} <- Cases],
    [ct:pal("~s: ~s", [What, describe(R)]) || {What, R} <- Results],
    case [{What, describe(R)} || {What, R} <- Results, not bounded(R)] of
        [] -> ok;
        Bad -> ct:fail({unbounded, Bad})
    end.

edge_scenes_stay_bounded(Config) ->
    Dir = ?config(priv_dir, Config),
    Counter = counters:new(1, []),
    Prop = ?FORALL({Scene, Flags}, edge_case(),
                   begin
                       N = counters:get(Counter, 1),
                       ok = counters:add(Counter, 1, 1),
                       File = scene_file(Dir, "edge_" ++ integer_to_list(N), Scene),
                       R = measured(["run", File, "--quiet" | Flags], 20),
                       ?WHENFAIL(ct:pal("~s~n~s ~s", [describe(R), jiffy:encode(Scene), lists:join(" ", Flags)]),
                                 collect(outcome(R), bounded(R)))
                   end),
    true = proper:quickcheck(Prop, [{numtests, 24}, {to_file, user}, long_result]).

%%% Generators

edge_case() ->
    ?LET({Count, Radius, Speed, CellFactor, {Substep, StrideSubsteps}, Gravity, Ccd, Container, Engine},
         {oneof([1, 2, 40, 400, 5000, 1000000]),
          oneof([1.0e-300, 1.0e-100, 1.0e-6, 0.1, 1.0, 1.0e6]),
          oneof([0.0, 1.0, 1.0e4, 1.0e8, 1.0e12]),
          oneof([none, 1.0e-3, 1.0, 1.0e6]),
          oneof([{0.001, 64000}, {0.001, 8}, {1, 64}, {1, 100000}, {100, 1}, {250, 4}]),
          oneof([none, [0, -9.81, 0], [0, -1.0e12, 0]]),
          boolean(), boolean(), oneof([timewarp, reference])},
         begin
             Side = 4.0 * Radius * (1.0 + math:pow(Count, 1 / 3)),
             Region = #{<<"min">> => [-Side, -Side, -Side], <<"max">> => [Side, Side, Side]},
             Gen = maps:merge(Region, #{<<"type">> => <<"random">>, <<"id_prefix">> => <<"s">>,
                                        <<"count">> => Count, <<"seed">> => 7, <<"radius">> => Radius,
                                        <<"mass">> => 1.0, <<"speed">> => Speed}),
             Fixtures = case Container of
                            true -> [box(2.0 * Side)];
                            false -> []
                        end,
             Model = maps:merge(#{<<"ccd">> => Ccd},
                                case Gravity of none -> #{}; G -> #{<<"gravity">> => G} end),
             Cell = case CellFactor of none -> #{}; F -> #{<<"cell_size">> => F * Radius} end,
             Scene = maps:merge(Cell, #{<<"name">> => <<"edge">>, <<"duration_ms">> => 20 * Substep,
                                        <<"substep_ms">> => Substep, <<"stride_ms">> => StrideSubsteps * Substep,
                                        <<"frame_ms">> => Substep, <<"model">> => Model,
                                        <<"bodies">> => Fixtures, <<"generators">> => [Gen]}),
             {Scene, ["--engine", atom_to_list(Engine)]}
         end).

one_sphere(Radius, Speed, Model) ->
    #{<<"name">> => <<"one">>, <<"duration_ms">> => 200, <<"model">> => Model,
      <<"bodies">> => [#{<<"id">> => <<"s">>, <<"shape">> => <<"sphere">>, <<"radius">> => Radius, <<"mass">> => 1.0,
                         <<"position">> => [0, 0, 0], <<"velocity">> => [Speed, 0, 0]}]}.

fast_sphere(Speed, Fixtures) ->
    S = one_sphere(0.1, Speed, #{<<"ccd">> => true}),
    S#{<<"bodies">> => Fixtures ++ maps:get(<<"bodies">>, S), <<"duration_ms">> => 2000}.

box(Half) ->
    #{<<"id">> => <<"box">>, <<"shape">> => <<"box">>, <<"static">> => true, <<"hollow">> => true,
      <<"half_extents">> => [Half, Half, Half], <<"position">> => [0, 0, 0]}.

scene_file(Dir, Name, Scene) ->
    File = filename:join(Dir, Name ++ ".json"),
    ok = file:write_file(File, jiffy:encode(Scene)),
    File.

%%% Measured runs

%% The escript with Args, its peak resident memory from getrusage (GNU
%% time's %M, in KiB), killed when its resident size passes the ceiling or
%% when it still runs after WallS seconds.
measured(Args, WallS) ->
    Dir = string:trim(os:cmd("mktemp -d")),
    Peak = filename:join(Dir, "peak"),
    Err = filename:join(Dir, "stderr"),
    Cmd = lists:flatten(["exec /usr/bin/time -f %M -o ", quote(Peak), " ", quote(rw_test_lib:escript()),
                         [[" ", quote(A)] || A <- Args], " >/dev/null 2>", quote(Err)]),
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, ["-c", Cmd]}, exit_status, binary, {cd, Dir}, {env, [{"HOME", Dir}]}]),
    {os_pid, TimePid} = erlang:port_info(Port, os_pid),
    T0 = erlang:monotonic_time(millisecond),
    End = watch(Port, TimePid, T0 + WallS * 1000, none),
    Wall = erlang:monotonic_time(millisecond) - T0,
    {ok, ErrText} = file:read_file(Err),
    PeakKb = case file:read_file(Peak) of
                 {ok, Text} -> last_integer(Text);
                 _ -> 0
             end,
    _ = os:cmd("rm -rf " ++ quote(Dir)),
    End#{peak_kb => max(PeakKb, maps:get(seen_kb, End, 0)), wall_ms => Wall, stderr => ErrText}.

%% Every 100 ms: the run's resident size; kill it past the ceiling or the
%% wall time (GNU time still reports the peak of a killed child).
watch(Port, TimePid, Deadline, Child0) ->
    receive
        {Port, {exit_status, S}} -> #{exit => S}
    after 100 ->
        Child = case Child0 of none -> child_of(TimePid); _ -> Child0 end,
        Rss = rss_kb(Child),
        Now = erlang:monotonic_time(millisecond),
        if
            Rss > ?CEILING_MB * 1024 ->
                kill(Child),
                (drain_exit(Port))#{killed => ceiling, seen_kb => Rss};
            Now > Deadline ->
                kill(Child),
                (drain_exit(Port))#{killed => wall_time, seen_kb => Rss};
            true ->
                watch(Port, TimePid, Deadline, Child)
        end
    end.

drain_exit(Port) ->
    receive {Port, {exit_status, S}} -> #{exit => S}
    after 30000 -> error(run_not_ended)
    end.

child_of(Pid) ->
    case string:lexemes(os:cmd("pgrep -P " ++ integer_to_list(Pid)), "\n") of
        [C | _] -> list_to_integer(string:trim(C));
        [] -> none
    end.

rss_kb(none) -> 0;
rss_kb(Pid) ->
    case file:read_file("/proc/" ++ integer_to_list(Pid) ++ "/status") of
        {ok, Status} ->
            case re:run(Status, "VmRSS:\\s+([0-9]+)", [{capture, all_but_first, list}]) of
                {match, [Kb]} -> list_to_integer(Kb);
                nomatch -> 0
            end;
        {error, _} -> 0
    end.

kill(none) -> ok;
kill(Pid) -> _ = os:cmd("kill -KILL " ++ integer_to_list(Pid)), ok.

last_integer(Text) ->
    case re:run(Text, "([0-9]+)\\s*$", [{capture, all_but_first, list}]) of
        {match, [N]} -> list_to_integer(N);
        nomatch -> 0
    end.

quote(S) -> "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".

peak_mb(#{peak_kb := Kb}) -> Kb div 1024.

%% Within the budget, and: ended with 0, refused with 2 in seconds with one
%% line, or still running (under the budget) when its wall time was up.
bounded(#{peak_kb := Kb}) when Kb > ?BUDGET_MB * 1024 -> false;
bounded(#{killed := ceiling}) -> false;
bounded(#{killed := wall_time}) -> true;
bounded(#{exit := 0}) -> true;
bounded(#{exit := 2, wall_ms := Wall, stderr := Err}) ->
    Wall =< ?REFUSAL_S * 1000 andalso length(string:lexemes(Err, "\n")) =:= 1;
bounded(#{}) -> false.

outcome(#{killed := K}) -> K;
outcome(#{exit := 0}) -> ran;
outcome(#{exit := 2}) -> refused;
outcome(#{exit := S}) -> {exit, S}.

describe(#{peak_kb := Kb, wall_ms := Wall, stderr := Err} = R) ->
    io_lib:format("~p, peak ~b MB, ~b ms; stderr: ~ts", [outcome(R), Kb div 1024, Wall,
                                                         string:slice(Err, 0, 400)]).
