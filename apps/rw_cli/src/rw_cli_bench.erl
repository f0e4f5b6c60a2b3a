%% `rigidwarp bench accuracy`: speed versus accuracy over a sweep of
%% substeps, strides, integrators and CCD (rw_accuracy measures), printed as
%% a table, written as CSV and drawn as a Pareto plot with gnuplot.
%% `rigidwarp bench machine`: how well this machine itself scales from 1 to 2
%% schedulers on work like the engine's, to read the engine's speedups against.
%% `rigidwarp bench parallelism`: rw_cli_parallelism; `rigidwarp bench
%% scale`: rw_cli_scale.
-module(rw_cli_bench).
-export([bench/1]).

-define(DEFAULT_CSV, "doc/bench/accuracy.csv").
-define(DEFAULT_PNG, "doc/bench/accuracy.png").
-define(VALUE_FLAGS, ["--scenes", "--until", "--substeps", "--strides", "--integrators", "--ccd", "--out",
                      "--plot"]).

-spec bench([string()]) -> 0 | 1.
bench(["accuracy" | Args]) -> accuracy(parse(Args, defaults()));
bench(["machine"]) -> machine(3);
bench(["machine", "--repeats", N]) -> machine(rw_cli_args:pos_int("--repeats", N));
bench(["machine" | _]) -> throw({usage, "bench machine takes only --repeats N"});
bench(["parallelism" | Args]) -> rw_cli_parallelism:bench(Args);
bench(["scale" | Args]) -> rw_cli_scale:bench(Args);
bench([]) -> throw({usage, "bench needs a benchmark: accuracy, machine, parallelism or scale"});
bench([Other | _]) -> throw({usage, "unknown benchmark " ++ Other ++ " (known: accuracy, machine, parallelism, scale)"}).

%%% The machine's own scaling (rw_machine)

machine(Repeats) ->
    io:put_chars([jiffy:encode(rw_machine:scaling(Repeats)), $\n]),
    0.

defaults() ->
    #{scenes => scenes("--scenes", string:join(rw_accuracy:default_scenes(), ",")),
      substeps => rw_accuracy:default_substeps(), strides => rw_accuracy:default_strides(),
      integrators => rw_integrate:integrators(), ccd => [false, true],
      out => ?DEFAULT_CSV, plot => ?DEFAULT_PNG, quiet => false}.

%%% Flags

parse([], Opts) -> Opts;
parse(["--quiet" | Rest], O) -> parse(Rest, O#{quiet => true});
parse(["--scenes", V | Rest], O) -> parse(Rest, O#{scenes => scenes("--scenes", V)});
parse(["--until", V | Rest], O) -> parse(Rest, O#{until => rw_cli_args:pos_ms("--until", V)});
parse(["--substeps", V | Rest], O) ->
    parse(Rest, O#{substeps => lists:usort([rw_cli_args:pos_ms("--substeps", X) || X <- items("--substeps", V)])});
parse(["--strides", V | Rest], O) ->
    parse(Rest, O#{strides => lists:usort([rw_cli_args:pos_ms("--strides", X) || X <- items("--strides", V)])});
parse(["--integrators", V | Rest], O) ->
    Known = [atom_to_list(I) || I <- rw_integrate:integrators()],
    Ints = [case lists:member(X, Known) of
                true -> list_to_atom(X);
                false -> throw({usage, "--integrators: unknown integrator " ++ X ++ " (known: "
                                ++ string:join(Known, ", ") ++ ")"})
            end || X <- items("--integrators", V)],
    parse(Rest, O#{integrators => dedup(Ints)});
parse(["--ccd", V | Rest], O) ->
    Ccd = [case X of
               "off" -> false;
               "on" -> true;
               _ -> throw({usage, "--ccd takes off, on or off,on; got " ++ X})
           end || X <- items("--ccd", V)],
    parse(Rest, O#{ccd => dedup(Ccd)});
parse(["--out", V | Rest], O) ->
    lists:suffix(".csv", V) orelse throw({usage, "--out must name a .csv file, got " ++ V}),
    parse(Rest, O#{out => V});
parse(["--plot", V | Rest], O) ->
    lists:suffix(".png", V) orelse throw({usage, "--plot must name a .png file, got " ++ V}),
    parse(Rest, O#{plot => V});
parse([[$- | _] = Flag | _], _) -> rw_cli_args:bad_flag(Flag, ?VALUE_FLAGS);
parse([Extra | _], _) -> throw({usage, "unexpected argument " ++ Extra}).

items(Flag, V) ->
    Items = string:split(V, ",", all),
    lists:member("", Items) andalso throw({usage, Flag ++ " takes a comma-separated list, got " ++ V}),
    Items.

dedup(L) -> lists:reverse(lists:foldl(fun(X, Acc) -> case lists:member(X, Acc) of
                                                         true -> Acc;
                                                         false -> [X | Acc]
                                                     end end, [], L)).

%% NAME or a file (rw_cli_scene:resolve/1), each with an optional :UNTIL_MS.
scenes(Flag, V) ->
    [case string:split(Item, ":", trailing) of
         [Name, Ms] when Name =/= "" ->
             {rw_cli_scene:resolve(Name), rw_cli_args:pos_ms(Flag ++ " " ++ Name ++ ":", Ms)};
         _ -> rw_cli_scene:resolve(Item)
     end || Item <- items(Flag, V)].

%%% The run

accuracy(#{out := Csv, plot := Png, quiet := Quiet} = Opts) ->
    Gnuplot = case os:find_executable("gnuplot") of
                  false -> throw({bad_input, "bench accuracy draws its plot with gnuplot: apt-get install gnuplot-nox"});
                  G -> G
              end,
    Counter = counters:new(1, []),
    Progress = fun(Row) ->
                       counters:add(Counter, 1, 1),
                       Quiet orelse io:put_chars(standard_error, progress_line(counters:get(Counter, 1), Row))
               end,
    Sweep = maps:with([scenes, substeps, strides, integrators, ccd, until], Opts),
    case rw_accuracy:sweep(Sweep#{on_row => Progress}) of
        {error, Msg} ->
            throw({bad_input, Msg});
        {ok, Rows} ->
            io:put_chars(rw_accuracy:table(Rows)),
            ok = rw_cli_report:write_atomically(Csv, rw_accuracy:csv(Rows)),
            case plot(Gnuplot, Rows, Png) of
                ok ->
                    io:format(standard_error, "rigidwarp: wrote ~ts and ~ts~n", [Csv, Png]),
                    0;
                {error, Why} ->
                    io:format(standard_error, "rigidwarp: wrote ~ts; gnuplot failed: ~ts~n",
                              [Csv, rw_cli_report:one_line(Why)]),
                    1
            end
    end.

progress_line(N, #{scene := S, substep_ms := Dt, stride_ms := St, integrator := I, ccd := C,
                   realtime_factor := Rt, pos_err_max := E, missed := M}) ->
    io_lib:format("rigidwarp: [~b] ~ts substep ~s ms stride ~s ms ~s ccd ~s: realtime x~ts, position error ~ts m,"
                  " ~b missed~n", [N, S, rw_cli_args:format_ms(Dt), rw_cli_args:format_ms(St), I,
                                   case C of true -> "on"; false -> "off" end,
                                   rw_accuracy:num(Rt), rw_accuracy:num(E), M]).

%%% The Pareto plot: one panel per scene, wall time per simulated second
%%% against the largest position error, both on log scales; integrators in
%%% colours, CCD off as open and on as filled points, the front as a line.

-define(FLOOR, 1.0e-15).

plot(Gnuplot, Rows, Png) ->
    Dir = string:trim(os:cmd("mktemp -d")),
    Scenes = dedup([S || #{scene := S} <- Rows]),
    Panels = [plot_data(Dir, K, S, [R || #{scene := S1} = R <- Rows, S1 =:= S])
              || {K, S} <- lists:zip(lists:seq(1, length(Scenes)), Scenes)],
    Cols = min(3, length(Scenes)),
    Lines = (length(Scenes) + Cols - 1) div Cols,
    Out = filename:join(Dir, "plot.png"),
    Script = [io_lib:format("set terminal pngcairo size ~b,~b font 'sans,10'~n"
                            "set output '~ts'~n"
                            "set multiplot layout ~b,~b title \"Speed versus accuracy: rigidwarp bench accuracy"
                            " (~ts; position errors below 1e-15 m drawn at 1e-15 m)\" noenhanced~n"
                            "set logscale xy~nset grid~nset format y '10^{%L}'~n"
                            "set xlabel 'wall s per simulated s (1 / realtime factor)'~n"
                            "set ylabel 'largest position error (m)'~n"
                            "set key below horizontal maxcols 4 samplen 1 spacing 1 font 'sans,10' noenhanced~n"
                            "set offsets graph 0.04, graph 0.04, graph 0.08, graph 0.08~n",
                            [560 * Cols, 520 * Lines + 40, Out, Lines, Cols, machine()]),
              Panels,
              "unset multiplot\n"],
    ScriptFile = filename:join(Dir, "plot.gp"),
    ok = file:write_file(ScriptFile, Script),
    Result = os:cmd(Gnuplot ++ " " ++ ScriptFile ++ " 2>&1"),
    %% a script gnuplot stops in leaves a picture behind all the same
    Failed = re:run(Result, "line [0-9]+: (?!warning)") =/= nomatch,
    Done = case (not Failed) andalso filelib:is_regular(Out) andalso filelib:ensure_dir(Png) =:= ok
               andalso file:copy(Out, Png) of
               {ok, _} -> ok;
               _ -> {error, string:trim(Result)}
           end,
    _ = file:del_dir_r(Dir),
    Done.

plot_data(Dir, K, Scene, Rows) ->
    Points = filename:join(Dir, io_lib:format("points~b.dat", [K])),
    Front = filename:join(Dir, io_lib:format("front~b.dat", [K])),
    Line = fun(#{realtime_factor := Rt, pos_err_max := E} = R) ->
                   io_lib:format("~.6e ~.6e ~b ~b~n", [1.0 / max(Rt, 1.0e-9), max(E, ?FLOOR),
                                                       integrator_index(maps:get(integrator, R)),
                                                       case maps:get(ccd, R) of true -> 1; false -> 0 end])
           end,
    ok = file:write_file(Points, [Line(R) || R <- Rows]),
    FrontRows = lists:sort(fun(#{realtime_factor := A}, #{realtime_factor := B}) -> A >= B end,
                           [R || #{pareto := true} = R <- Rows]),
    ok = file:write_file(Front, [Line(R) || R <- FrontRows]),
    %% one legend, under the first panel: the series are the same in every panel
    Title = fun(Text) when K =:= 1 -> io_lib:format("title '~s'", [Text]);
               (_) -> "notitle"
            end,
    Series = [io_lib:format("'~ts' using 1:(($3 == ~b && $4 == ~b) ? $2 : 1/0) with points pt ~b ps 1.2 lc ~b ~s",
                            [Points, I, C, case C of 0 -> 6; 1 -> 7 end, I + 1,
                             Title(io_lib:format("~s, CCD ~s", [Name, case C of 0 -> "off"; 1 -> "on" end]))])
              || {I, Name} <- [{0, "symplectic Euler"}, {1, "Verlet"}, {2, "explicit Euler"}], C <- [0, 1]],
    [io_lib:format("set title '~ts' noenhanced~n", [Scene]),
     "plot ", lists:join(", \\\n     ", Series),
     io_lib:format(", \\\n     '~ts' using 1:2 with linespoints lw 1.5 pt 4 ps 2 lc rgb 'black' ~s~n",
                   [Front, Title("Pareto front")])].

integrator_index(symplectic_euler) -> 0;
integrator_index(verlet) -> 1;
integrator_index(explicit_euler) -> 2.

machine() ->
    Cpu = case file:read_file("/proc/cpuinfo") of
              {ok, Info} ->
                  case re:run(Info, "model name\\s*:\\s*([^\\n]*)", [{capture, all_but_first, list}]) of
                      {match, [Model]} -> ", " ++ string:trim(Model);
                      nomatch -> ""
                  end;
              _ -> ""
          end,
    lists:flatten(io_lib:format("~b cores~ts, OTP ~s", [erlang:system_info(logical_processors), Cpu,
                                                        erlang:system_info(otp_release)])).
