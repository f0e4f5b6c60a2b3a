%% The `rigidwarp` escript: its commands, their help text and exit codes.
%% Exit codes: 0 ok, 2 bad input (flags or scene), 1 runtime failure.
-module(rw_cli).
-export([main/1]).

-define(RUN_HELP,
"  run SCENE [options]        run a scene; the summary JSON is the last line on stdout
      --engine ENGINE        timewarp (default, parallel) or reference (sequential oracle)
      --schedulers N         scheduler threads for the timewarp engine (default: all cores;
                             with --nodes, of each node)
      --nodes N              timewarp: run over N Erlang nodes, this one and N-1 peer nodes
                             started here (loopback only) and stopped at the end
      --connect A@H,B@H      timewarp: run over this node and running nodes A@H, B@H, ...
      --cookie COOKIE        with --connect: the nodes' cookie (default: $RIGIDWARP_COOKIE,
                             else ~/.erlang.cookie); the summary then says what the nodes
                             sent each other (cross_node_*, in all and per simulated second)
                             and how often bodies were placed anew (migrations)
      --buckets N            TVHT bucket processes (default: the scene's buckets, else 64)
      --frames FILE          write committed frames as JSON Lines to FILE (- for stdout);
                             a file is written as FILE.part with FILE.checkpoint beside it
                             and renamed to FILE at the end
      --resume               continue an interrupted run with the same --frames FILE and
                             options from its last checkpoint (starts over if there is none)
      --until MS             simulate up to MS milliseconds (default: the scene's duration_ms)
      --substep MS           substep in ms, 0.001 at the finest (default: the scene's substep_ms)
      --stride MS            LVT_ub - GVT in ms (default: the scene's stride_ms)
      --frame-ms MS          frame interval in ms (default: the scene's frame_ms)
      --integrator NAME      symplectic_euler, verlet or explicit_euler (default: the scene's)
      --ccd on|off           swept (continuous) collision tests (default: the scene's)
      --groups on|off        timewarp: step bodies in persistent contact as one entity
                             (default on; off is the paper's one entity per body)
      --group-max N          timewarp: the most bodies in one contact group (default 1024,
                             at most 4096)
      --native on|off        timewarp: the engine's C loops where their library loads (default
                             on); off runs its Erlang code alone, slower, with the same frames;
                             the summary's native says whether they ran (on every node)
      --speculation-mb N     timewarp: the memory in MiB that the bodies' history past GVT may
                             take (default 1024); where the stride would need more, bodies
                             step ahead of GVT by a shorter one (the summary's
                             effective_stride_ms), and while the run holds more than that
                             they step less far (memory_holds counts the cuts); either makes
                             throttled true; the frames are the same
      --quiet                no progress line on stderr
      the summary's keys in this order (those the run has; any others follow, sorted):
                             scene, engine, bodies, substep_ms, stride_ms, sim_ms, wall_ms,
                             realtime_factor, frames, native, then
                             timewarp: effective_stride_ms, throttled, memory_holds, events,
                             antievents, rollbacks, primary_rollbacks, secondary_rollbacks,
                             rolled_back_substeps, computed_substeps, committed_substeps,
                             efficiency, steps, regroups, restarts, nodes,
                             cross_node_messages, cross_node_bytes,
                             cross_node_messages_per_s, cross_node_bytes_per_s, migrations,
                             resumed_from_ms;
                             reference: substeps, body_substeps, pair_contacts, fixture_contacts,
                             resumed_from_ms
").
-define(VALIDATE_HELP,
"  validate SCENE             check a scene and say what is wrong with it
").
-define(SCENES_HELP,
"  scenes [DIR]               list the scenes in DIR (default: the scenarios directory where
                             SCENE names are looked up): file, bodies, duration in ms, the box
                             the bodies start in, then the whole description
").
-define(VIEW_HELP,
"  view FRAMES.jsonl --scene SCENE [--port N]
                             serve the 3D viewer on http://127.0.0.1:N/ (default 8765)
                             playing back a frames file written by run --frames of SCENE
                             (frames of other bodies are refused)
  view --live SCENE [run options] [--port N]
                             run the scene on the timewarp engine and watch it live, with
                             run's progress line on stderr and its summary on stdout at the
                             end; the viewer serves on until Ctrl-C
").
-define(SNAPSHOT_HELP,
"  snapshot FRAMES.jsonl --scene SCENE --at MS --out FILE.png
                             a picture of the frame at MS (front view, x right, y up;
                             gnuplot), without a browser; MS within the file's times
").
-define(BENCH_HELP,
"  bench accuracy [options]   speed versus accuracy: sweeps substep, stride, integrator and CCD
                             over analytic scenes, measured against their exact solution;
                             a table on stdout, a CSV file and a Pareto plot (gnuplot)
      --scenes A,B           scenes (files or NAMEs, as SCENE below), each optionally
                             NAME:MS to end at MS (default: projectile, ball_drop,
                             head_on_elastic, newtons_cradle, fast_thin_wall, bouncing_50_250:1000)
      --until MS             end time of the scenes without their own (default: duration_ms)
      --substeps LIST        substeps in ms (default 0.5,1,2,4,8,16)
      --strides LIST         strides in ms, rounded up to the substep (default 16,64,256)
      --integrators LIST     from symplectic_euler,verlet,explicit_euler (default: all three)
      --ccd LIST             off,on (default), off or on
      --out FILE.csv         the CSV file (default doc/bench/accuracy.csv)
      --plot FILE.png        the Pareto plot (default doc/bench/accuracy.png)
      --quiet                no progress lines on stderr
  bench machine [--repeats N]
                             this machine's own 1 -> 2 scheduler scaling, without the engine:
                             two processes doing allocation-heavy Erlang work (as the engine's
                             bodies do) on 1 and then 2 schedulers, N alternating pairs
                             (default 3); one JSON line (the 2-core floor is judged against it)
  bench parallelism [SCENE...] [--until MS] [--repeats N]
                             how the scenes' work would spread over more cores: one run on one
                             scheduler records every task with its cost and dependencies, then
                             the total work, the critical path, the average parallelism and a
                             list schedule's speedup on 2, 4, 8, 16 and 64 cores; beside them the
                             1 -> 2 scheduler speedup measured here (N alternating pairs, default
                             3, median). A markdown table, then one JSON line. Default scenes: the
                             paper's eight and pile_300, heap_500, stack_1000; --until default 1000
  bench scale [--counts N,N,...] [--until MS] [--rounds N] [--scenes DIR]
                             the cost of a body-substep as scenes grow: gases at Bouncing 500's
                             density of 500, 2000, 5000, 10000 and 20000 spheres (default), each
                             run on every scheduler to MS (default 500; small gases several
                             times, to at least 5 million body-substeps, at most 20 runs):
                             body-substeps per second, over the runs and once every body runs,
                             and memory per body a quarter, half and three quarters of the way.
                             With N rounds (default 1) every count runs once a round, the order
                             reversed each round: medians, and the median and range of the
                             rounds' ratios to the first count. A markdown table, then one JSON
                             line. With --scenes, runs nothing: writes the gases as scene files
                             DIR/gas_N.json that run to MS, and prints their paths
").
-define(VERSION_HELP,
"  version, --version         the rigidwarp version and the Erlang/OTP release it runs on
").
-define(SCENE_HELP,
"SCENE is a scene file, or the NAME of one: scenarios/NAME.json in the current directory, else
in the rigidwarp checkout whose _build/PROFILE/bin holds this escript (rigidwarp scenes lists them)
").
-define(USAGE,
"usage: rigidwarp <command> [options]

commands:
" ?RUN_HELP ?VALIDATE_HELP ?SCENES_HELP ?VIEW_HELP ?SNAPSHOT_HELP ?BENCH_HELP
?VERSION_HELP
"  help                       this text; rigidwarp COMMAND --help for one command

" ?SCENE_HELP "
exit codes: 0 ok, 1 runtime failure, 2 bad input (the message names the field or flag)
").

-spec main([string()]) -> no_return().
main(Args) ->
    _ = logger:remove_handler(default),
    _ = logger:add_handler(stderr, logger_std_h, #{config => #{type => standard_error},
                                              formatter => {logger_formatter, #{single_line => true}}}),
    Code = try dispatch(Args)
           catch
               throw:{usage, Msg} ->
                   io:format(standard_error, "rigidwarp: ~ts (see rigidwarp help)~n", [rw_cli_report:one_line(Msg)]),
                   2;
               throw:{bad_input, Msg} ->
                   io:format(standard_error, "rigidwarp: ~ts~n", [rw_cli_report:one_line(Msg)]),
                   2;
               error:terminated ->
                   %% stdout was closed (`rigidwarp scenes | head`): stop quietly,
                   %% with the exit status of a process killed by SIGPIPE
                   141;
               Class:Reason:Stack ->
                   io:format(standard_error, "rigidwarp: internal error: ~p:~p~n~p~n", [Class, Reason, Stack]),
                   1
           end,
    halt(Code).

dispatch([]) -> io:put_chars(standard_error, ?USAGE), 2;
dispatch([Help | _]) when Help =:= "help"; Help =:= "--help"; Help =:= "-h" ->
    io:put_chars(?USAGE), 0;
dispatch(["--version" | Args]) -> command("version", Args);
dispatch([Cmd | Args]) ->
    case lists:member("--help", Args) orelse lists:member("-h", Args) of
        true -> io:put_chars(["usage: rigidwarp ", string:trim(command_help(Cmd)), "\n"]), 0;
        false -> command(Cmd, Args)
    end.

command_help("run") -> ?RUN_HELP "\n" ?SCENE_HELP;
command_help("validate") -> ?VALIDATE_HELP "\n" ?SCENE_HELP;
command_help("scenes") -> ?SCENES_HELP;
command_help("view") -> ?VIEW_HELP "\n" ?SCENE_HELP;
command_help("snapshot") -> ?SNAPSHOT_HELP "\n" ?SCENE_HELP;
command_help("bench") -> ?BENCH_HELP;
command_help("version") -> ?VERSION_HELP;
command_help(Cmd) -> throw({usage, "unknown command " ++ Cmd}).

command("run", Args) -> run(Args, rw_cli_args:parse(Args));
command("validate", [Arg]) ->
    File = rw_cli_scene:resolve(Arg),
    case rigidwarp:load(File, #{}) of
        {ok, _} -> io:format("~ts: ok~n", [File]), 0;
        {error, Msg} -> throw({bad_input, Msg})
    end;
command("validate", _) -> throw({usage, "validate takes exactly one scene file"});
command("scenes", []) -> rw_cli_scene:list(default);
command("scenes", [Dir]) -> rw_cli_scene:list(Dir);
command("scenes", _) -> throw({usage, "scenes takes at most one directory"});
command("view", Args) -> rw_cli_view:view(Args);
command("snapshot", Args) -> rw_cli_view:snapshot(Args);
command("bench", Args) -> rw_cli_bench:bench(Args);
command("version", []) -> io:format("~ts~n", [version()]), 0;
command("version", [Extra | _]) -> throw({usage, "version takes no arguments, got " ++ Extra});
command(Cmd, _) -> throw({usage, "unknown command " ++ Cmd}).

%% The rigidwarp application's vsn, read from its .app (in the escript's
%% archive, as anywhere else), and the OTP release and runtime.
version() ->
    _ = application:load(rigidwarp),
    Vsn = case application:get_key(rigidwarp, vsn) of
              {ok, V} -> V;
              undefined -> "unknown"
          end,
    io_lib:format("rigidwarp ~ts (Erlang/OTP ~ts, erts ~ts)",
                  [Vsn, erlang:system_info(otp_release), erlang:system_info(version)]).

run(Args, {Arg, Opts, Quiet}) ->
    File = rw_cli_scene:resolve(Arg),
    %% from the start, so that no signal meets OTP's default handler
    ok = rw_cli_signals:install(self()),
    %% a bad frames path is refused before anything is loaded or created
    Resume = maps:get(resume, Opts, false),
    Frames = maps:find(frames, Opts),
    case Frames of
        {ok, Path} ->
            case rw_output:check(Path, Resume) of
                ok -> ok;
                {error, Msg0} -> throw({bad_input, Msg0})
            end;
        error -> ok
    end,
    {ok, Scene} = case rigidwarp:load(File, Opts) of
                      {ok, _} = Ok -> Ok;
                      {error, Msg} -> throw({bad_input, Msg})
                  end,
    Total = rw_scene:duration_ms(Scene),
    {Progress, Finish} = case Quiet of
                             true -> {#{}, fun() -> ok end};
                             false -> rw_cli_report:progress(Total, rw_cli_report:is_terminal())
                         end,
    Result = try
                 rigidwarp:run_scene(Scene, maps:merge(Opts, Progress))
             catch
                 Class:Raised:Stack ->
                     %% a run that a signal stopped ends as stopped, whatever
                     %% the engine's processes did on the way down
                     case rw_cli_signals:received() of
                         none -> erlang:raise(Class, Raised, Stack);
                         Sig -> {error, {interrupted, Sig, undefined}}
                     end
             after
                 Finish()
             end,
    case Result of
        {ok, Summary} ->
            io:put_chars([rw_cli_report:summary_json(Summary), $\n]),
            0;
        {error, {interrupted, Signal, LastMs}} ->
            io:format(standard_error, "~ts~n", [interrupted(Args, Frames, LastMs)]),
            rw_cli_signals:exit_code(Signal);
        {error, Reason} ->
            io:format(standard_error, "rigidwarp: ~ts~n", [rw_cli_report:one_line(rigidwarp:format_error(Reason))]),
            1
    end.

%% The line telling how to continue a stopped run: the same command with
%% --resume, when its frames went to a file that can be resumed.
interrupted(Args, Frames, LastMs) ->
    At = case is_number(LastMs) of
             true -> ["rigidwarp: interrupted at t=", rw_cli_args:format_ms(LastMs), " ms"];
             false -> "rigidwarp: interrupted"
         end,
    case Frames of
        error ->
            [At, " (no --frames file to resume)"];
        {ok, Path} ->
            case rw_output:check(Path, true) of
                ok ->
                    Again = case lists:member("--resume", Args) of
                                true -> Args;
                                false -> Args ++ ["--resume"]
                            end,
                    [At, "; continue with: rigidwarp run ", lists:join(" ", [rw_cli_args:shell_quote(A) || A <- Again])];
                {error, _} ->
                    [At, " (frames to ", Path, " cannot be resumed)"]
            end
    end.
