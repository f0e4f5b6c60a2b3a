%% `rigidwarp view` (the browser viewer, live or playing back a frames file)
%% and `rigidwarp snapshot` (one frame as a PNG through gnuplot).
-module(rw_cli_view).
-include_lib("rigidwarp/include/rigidwarp.hrl").
-export([view/1, snapshot/1, load_frames/1]).

-spec view([string()]) -> 1.  % 1 if the server cannot start; otherwise it serves until killed
view(Args) ->
    {Port, Rest} = take_value("--port", Args),
    %% without --port, the viewer's own default (the viewer_port setting)
    PortNum = case Port of
                  undefined -> default;
                  P -> port("--port", P)
              end,
    case Rest of
        ["--live" | RunArgs] ->
            live(RunArgs, PortNum);
        _ ->
            {FramesFile, SceneFile} = frames_and_scene(Rest, "view"),
            Scene = load_scene(SceneFile),
            Frames = load_frames(FramesFile),
            ok = check_frames(Scene, Frames, FramesFile, SceneFile),
            case serve({playback, Scene, Frames}, PortNum) of
                ok -> receive after infinity -> 1 end;
                failed -> 1
            end
    end.

%% view --live: the run goes on in the background while the viewer serves;
%% this process follows it with run's progress line and prints run's
%% summary when it ends, then the viewer serves on.
live(RunArgs, PortNum) ->
    {Arg, Opts, Quiet} = rw_cli_args:parse(RunArgs),
    File = rw_cli_scene:resolve(Arg),
    maps:get(engine, Opts, timewarp) =:= timewarp
        orelse throw({usage, "view --live runs the timewarp engine only"}),
    maps:is_key(frames, Opts) andalso throw({usage, "view --live does not take --frames"}),
    RunOpts = maps:without([engine], Opts),
    Scene = case rigidwarp:load(File, RunOpts) of
                {ok, S} -> S;
                {error, Msg} -> throw({bad_input, Msg})
            end,
    ok = rw_viewer:prepare(),
    Sim = case rigidwarp:start(File, RunOpts) of
              {ok, Started} -> Started;
              {error, Msg1} -> throw({bad_input, Msg1})
          end,
    case serve({live, Sim}, PortNum) of
        ok ->
            {OnProgress, Finish} = case Quiet of
                                       true -> {fun(_) -> ok end, fun() -> ok end};
                                       false ->
                                           {#{on_progress := F}, Fin} =
                                               rw_cli_report:progress(rw_scene:duration_ms(Scene),
                                                                      rw_cli_report:is_terminal()),
                                           {F, Fin}
                                   end,
            follow(Sim, Scene, OnProgress, Finish),
            receive after infinity -> 1 end;
        failed -> 1
    end.

%% The run's progress as often as the line is redrawn, until it ends
%% (start/2 made this process its owner, which hears of the end).
follow(Sim, Scene, OnProgress, Finish) ->
    receive
        {rw_done, _, _} ->
            Stats = rigidwarp:stats(Sim),
            OnProgress(Stats),
            Finish(),
            io:put_chars([rw_cli_report:summary_json(rw_cli_report:live_summary(Scene, Stats)), $\n]);
        {rw_crashed, _, Who, Reason} ->
            Finish(),
            io:format(standard_error, "rigidwarp: ~ts; the viewer shows its frames so far~n",
                      [rw_cli_report:one_line(rigidwarp:format_error({crashed, Who, Reason}))])
    after 250 ->
            case rigidwarp:stats(Sim) of
                #{status := running} = Stats -> OnProgress(Stats);
                _ -> ok
            end,
            follow(Sim, Scene, OnProgress, Finish)
    end.

serve(Source, PortNum) ->
    case rw_viewer:start(Source, case PortNum of default -> #{}; _ -> #{port => PortNum} end) of
        {ok, Server} ->
            Url = rw_viewer:url(Server),
            io:format("~s~n", [Url]),
            io:format(standard_error, "rigidwarp: viewer at ~s (~s); Ctrl-C to stop~n",
                      [Url, element(1, Source)]),
            ok;
        {error, Msg} ->
            io:format(standard_error, "rigidwarp: ~ts~n", [rw_cli_report:one_line(Msg)]),
            failed
    end.

-spec snapshot([string()]) -> 0 | 1.
snapshot(Args) ->
    {At, R1} = take_value("--at", Args),
    {Out, R2} = take_value("--out", R1),
    At =:= undefined andalso throw({usage, "snapshot needs --at MS"}),
    Out =:= undefined andalso throw({usage, "snapshot needs --out FILE.png"}),
    AtMs = non_neg("--at", At),
    lists:suffix(".png", Out) orelse throw({usage, "--out must name a .png file, got " ++ Out}),
    {FramesFile, SceneFile} = frames_and_scene(R2, "snapshot"),
    Scene = load_scene(SceneFile),
    Frames = load_frames(FramesFile),
    ok = check_frames(Scene, Frames, FramesFile, SceneFile),
    Times = [T || {frame, T, _} <- Frames],
    {First, Last} = {lists:min(Times), lists:max(Times)},
    AtMs >= First andalso AtMs =< Last orelse
        throw({bad_input, io_lib:format("--at ~b is outside the times of ~ts: ~ts..~ts ms",
                                        [AtMs, FramesFile, rw_cli_args:format_ms(First),
                                         rw_cli_args:format_ms(Last)])}),
    Frame = lists:last([F || {frame, T, _} = F <- Frames, T =< AtMs]),
    case os:find_executable("gnuplot") of
        false ->
            io:put_chars(standard_error, "rigidwarp: snapshot needs gnuplot (apt-get install gnuplot-nox)\n"),
            1;
        Gnuplot ->
            plot(Gnuplot, Scene, Frame, Out)
    end.

%% Frames that the scene did not make are refused before anything starts:
%% every frame holds exactly the scene's dynamic bodies.
check_frames(#scene{spheres = Spheres}, Frames, FramesFile, SceneFile) ->
    Ids = lists:sort([Id || #sphere{id = Id} <- Spheres]),
    Known = maps:from_keys(Ids, true),
    lists:foreach(
      fun({frame, T, Bodies}) ->
              Have = [element(1, B) || B <- Bodies],
              lists:sort(Have) =:= Ids orelse
                  throw({bad_input, mismatch(T, Have, Ids, Known, FramesFile, SceneFile)})
      end, Frames).

mismatch(T, Have, Ids, Known, FramesFile, SceneFile) ->
    At = rw_cli_args:format_ms(T),
    case [Id || Id <- Have, not is_map_key(Id, Known)] of
        [Stranger | _] ->
            io_lib:format("~ts: body ~ts in the frame at t=~s ms is not a dynamic body of ~ts (the frame has ~s, "
                          "the scene ~b): frames of another scene?",
                          [FramesFile, Stranger, At, SceneFile, bodies(length(Have)), length(Ids)]);
        [] when length(Have) =/= length(Ids) ->
            io_lib:format("~ts: the frame at t=~s ms has ~s, ~ts has ~s: frames of another scene?",
                          [FramesFile, At, bodies(length(Have)), SceneFile, bodies(length(Ids))]);
        [] ->
            [Missing | _] = Ids -- Have,
            io_lib:format("~ts: the frame at t=~s ms lacks body ~ts of ~ts", [FramesFile, At, Missing, SceneFile])
    end.

bodies(1) -> "1 body";
bodies(N) -> integer_to_list(N) ++ " bodies".

%% A front view (x right, y up): every sphere a circle of its radius,
%% cylinders along z as circles, planes as lines, boxes as rectangles.
plot(Gnuplot, #scene{name = Name, spheres = Spheres, fixtures = Fixtures}, {frame, T, Bodies}, Out) ->
    Dir = string:trim(os:cmd("mktemp -d")),
    Data = filename:join(Dir, "spheres.dat"),
    Radius = maps:from_list([{Id, R} || #sphere{id = Id, radius = R} <- Spheres]),
    ok = file:write_file(Data, [io_lib:format("~.17g ~.17g ~.17g~n", [float(X), float(Y), maps:get(Id, Radius, 0.1)])
                                || {Id, {X, Y, _}, _, _, _} <- Bodies]),
    {Xs, Ys} = lists:unzip([{X, Y} || {_, {X, Y, _}, _, _, _} <- Bodies]),
    Pad = 1.0 + lists:max([0.1 | maps:values(Radius)]),
    {X0, X1, Y0, Y1} = bounds(Xs, Ys, Fixtures, Pad),
    Objects = lists:append([fixture_object(F) || F <- Fixtures]),
    Script = [io_lib:format("set terminal pngcairo size 1000,800 font 'sans,11'~n"
                            "set output '~ts'~n"
                            "set title '~ts  t = ~p ms  (front view: x right, y up)' noenhanced~n"
                            "set size ratio -1~nset key off~nset grid~n"
                            "set xrange [~g:~g]~nset yrange [~g:~g]~n", [Out, Name, T, X0, X1, Y0, Y1]),
              Objects,
              io_lib:format("plot '~ts' using 1:2:3 with circles fill solid 0.6 lc rgb '#3b7dd8'~n", [Data])],
    ScriptFile = filename:join(Dir, "plot.gp"),
    ok = file:write_file(ScriptFile, Script),
    Result = os:cmd(Gnuplot ++ " " ++ ScriptFile ++ " 2>&1"),
    _ = file:del_dir_r(Dir),
    case filelib:is_regular(Out) of
        true -> io:format("~ts~n", [Out]), 0;
        false -> io:format(standard_error, "rigidwarp: gnuplot failed: ~ts~n", [rw_cli_report:one_line(Result)]), 1
    end.

bounds(Xs, Ys, Fixtures, Pad) ->
    Extra = lists:append([case S of
                              {cylinder, {CX, CY, _}, _, R, _} -> [{CX - R, CY - R}, {CX + R, CY + R}];
                              {box, {CX, CY, _}, {HX, HY, _}, _} -> [{CX - HX, CY - HY}, {CX + HX, CY + HY}];
                              _ -> []
                          end || #fixture{shape = S} <- Fixtures]),
    AllX = Xs ++ [X || {X, _} <- Extra],
    AllY = Ys ++ [Y || {_, Y} <- Extra],
    {lists:min(AllX) - Pad, lists:max(AllX) + Pad, lists:min(AllY) - Pad, lists:max(AllY) + Pad}.

fixture_object(#fixture{shape = {cylinder, {CX, CY, _}, _, R, _}}) ->
    [io_lib:format("set object circle at ~g,~g size ~g fc rgb '#888888' fs solid 0.8 behind~n", [CX, CY, R])];
fixture_object(#fixture{shape = {box, {CX, CY, _}, {HX, HY, _}, Kind}}) ->
    Fill = case Kind of hollow -> "empty border lc rgb '#555555'"; solid -> "solid 0.8" end,
    [io_lib:format("set object rectangle from ~g,~g to ~g,~g fc rgb '#888888' fs ~s behind~n",
                   [CX - HX, CY - HY, CX + HX, CY + HY, Fill])];
fixture_object(#fixture{shape = {plane, {NX, NY, _}, D}}) when abs(NY) > 1.0e-9 ->
    plane_line(NX, NY, D);
fixture_object(_) -> [].

%% The solid side of n.p = d seen from the front: y = (d - nx x) / ny,
%% filled away from the normal.
plane_line(NX, NY, D) ->
    [io_lib:format("set object polygon from -1e6,~g to 1e6,~g to 1e6,~g to -1e6,~g fc rgb '#666666' fs solid 0.5 behind~n",
                   [(D + NX * 1.0e6) / NY, (D - NX * 1.0e6) / NY, (D - NX * 1.0e6) / NY - 1.0e6,
                    (D + NX * 1.0e6) / NY - 1.0e6]) || NY > 0] ++
    [io_lib:format("set object polygon from -1e6,~g to 1e6,~g to 1e6,~g to -1e6,~g fc rgb '#666666' fs solid 0.5 behind~n",
                   [(D + NX * 1.0e6) / NY, (D - NX * 1.0e6) / NY, (D - NX * 1.0e6) / NY + 1.0e6,
                    (D + NX * 1.0e6) / NY + 1.0e6]) || NY < 0].

%%% Arguments and files

frames_and_scene(Args, Cmd) ->
    {Scene, Rest} = take_value("--scene", Args),
    case {Rest, Scene} of
        {[Frames], S} when S =/= undefined -> {Frames, rw_cli_scene:resolve(S)};
        {_, undefined} -> throw({usage, Cmd ++ " needs --scene SCENE.json (the scene the frames came from)"});
        {[], _} -> throw({usage, Cmd ++ " needs a frames file"});
        {[[$- | _] = Flag | _], _} -> throw({usage, "unknown flag " ++ Flag});
        {[_, Extra | _], _} -> throw({usage, "unexpected argument " ++ Extra})
    end.

take_value(Flag, Args) -> take_value(Flag, Args, []).

take_value(_Flag, [], Acc) -> {undefined, lists:reverse(Acc)};
take_value(Flag, [Flag], _Acc) -> throw({usage, Flag ++ " needs a value"});
take_value(Flag, [Flag, V | Rest], Acc) -> {V, lists:reverse(Acc, Rest)};
take_value(Flag, [A | Rest], Acc) -> take_value(Flag, Rest, [A | Acc]).

port(Flag, V) ->
    case catch list_to_integer(V) of
        N when is_integer(N), N >= 0, N =< 65535 -> N;
        _ -> throw({usage, Flag ++ " must be a port number 0-65535, got " ++ V})
    end.

non_neg(Flag, V) ->
    case catch list_to_integer(V) of
        N when is_integer(N), N >= 0 -> N;
        _ -> throw({usage, Flag ++ " must be a non-negative integer (ms), got " ++ V})
    end.

load_scene(File) ->
    case rigidwarp:load(File, #{}) of
        {ok, Scene} -> Scene;
        {error, Msg} -> throw({bad_input, Msg})
    end.

%% Every line of a frames file, or a bad_input naming the first bad line.
-spec load_frames(string()) -> [rw_reference:frame()].
load_frames(File) ->
    Bin = case file:read_file(File) of
              {ok, B} -> B;
              {error, Reason} -> throw({bad_input, io_lib:format("~ts: cannot read frames file: ~ts",
                                                                 [File, file:format_error(Reason)])})
          end,
    Lines = [L || L <- binary:split(Bin, <<"\n">>, [global]), L =/= <<>>],
    Lines =:= [] andalso throw({bad_input, io_lib:format("~ts: no frames in the file", [File])}),
    {Frames, _} = lists:mapfoldl(
                    fun(Line, N) ->
                            try {rw_frames:decode(Line), N + 1}
                            catch _:_ -> throw({bad_input, io_lib:format("~ts:~b: not a frame line "
                                                                         "(expected {\"t\":..., \"bodies\":[...]})",
                                                                         [File, N])})
                            end
                    end, 1, Lines),
    Frames.
