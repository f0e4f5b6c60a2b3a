%% Runs that write frames, interrupted and resumed through the escript as a
%% user runs it: SIGKILL at random moments, SIGTERM, ignored SIGUSR1/2,
%% outputs that are not regular files, paths refused before the run, and a
%% full device. A resumed run must end with the very bytes of a run that
%% was never interrupted.
-module(resume_SUITE).
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include_lib("kernel/include/file.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([kill_9_and_resume/1, kill_9_and_resume_reference/1, sigterm/1, sighup_sigquit/1, sigusr1_ignored/1,
         frames_to_device_fifo_stdout/1, bad_output_paths/1, full_disk/1]).

suite() -> [{timetrap, {minutes, 3}}].

all() -> [bad_output_paths, kill_9_and_resume, kill_9_and_resume_reference, sigterm, sighup_sigquit, sigusr1_ignored,
          frames_to_device_fifo_stdout, full_disk].

%% About 2 s of wall time each here (17 and 9 MB of frames), so that a
%% kill lands after a checkpoint (one a second) often enough.
timewarp_args() -> [rw_test_lib:scenario("cylinders_500.json"), "--until", "2000", "--quiet"].
reference_args() -> [rw_test_lib:scenario("bouncing_200_250.json"), "--until", "3000", "--engine", "reference",
                     "--quiet"].

%% The frames of uninterrupted runs, made once, and their wall times.
init_per_suite(Config) ->
    Dir = ?config(priv_dir, Config),
    Tw = filename:join(Dir, "timewarp.jsonl"),
    Ref = filename:join(Dir, "reference.jsonl"),
    [{timewarp_frames, Tw}, {timewarp_wall, uninterrupted(timewarp_args(), Tw)},
     {reference_frames, Ref}, {reference_wall, uninterrupted(reference_args(), Ref)} | Config].

uninterrupted(Args, Frames) ->
    T0 = erlang:monotonic_time(millisecond),
    {0, _, _} = rw_test_lib:run_escript(["run" | Args] ++ ["--frames", Frames]),
    erlang:monotonic_time(millisecond) - T0.

end_per_suite(_Config) -> ok.

%% ---------------------------------------------------------------- kills

kill_9_and_resume(Config) ->
    kills(Config, "kills_timewarp", timewarp_args(), ?config(timewarp_frames, Config), ?config(timewarp_wall, Config),
          5, {1, 2, 3}).

kill_9_and_resume_reference(Config) ->
    kills(Config, "kills_reference", reference_args(), ?config(reference_frames, Config),
          ?config(reference_wall, Config), 3, {4, 5, 6}).

%% Kills runs Times times (the first run fresh, the next ones with
%% --resume), each once the frames file holds a random share of what is
%% left to write, the first one late enough for a checkpoint to be there
%% (kill_at/6); after each kill FILE.part holds
%% whole frame lines (but perhaps a torn last one), a prefix of the
%% uninterrupted run's; a last --resume
%% completes the run, byte for byte the uninterrupted one.
kills(Config, Name, Args, Expected, _Wall, Times, Seed) ->
    Dir = workdir(Config, Name),
    F = filename:join(Dir, "f.jsonl"),
    {ok, Want} = file:read_file(Expected),
    _ = rand:seed(exsss, Seed),
    Run = fun(K) -> ["run" | Args] ++ ["--frames", F] ++ [R || K > 1, R <- ["--resume"]] end,
    Rounds = [begin
                  From = checkpoint_ms(F),
                  %% killed once the frames file holds a random share of what
                  %% is left to write (the first run not before its first
                  %% checkpoint), however fast the machine is at the time
                  Offset = checkpoint_offset(F),
                  Least = case K of 1 -> 0.3; _ -> 0.1 end,
                  Target = Offset + round((byte_size(Want) - Offset) * (Least + (0.9 - Least) * rand:uniform())),
                  {Port, Pid} = start(Run(K), Dir),
                  Delay = kill_at(Port, Pid, F, Target, K =:= 1, erlang:monotonic_time(millisecond)),
                  case wait(Port) of
                      {137, _} ->
                          Part = case file:read_file(F ++ ".part") of
                                     {ok, P} -> P;
                                     {error, enoent} -> <<>>
                                 end,
                          assert_lines_but_the_last(Part),
                          ?assertEqual(Part, binary:part(Want, 0, byte_size(Part))),
                          {killed, Delay, From, byte_size(Part)};
                      {0, _} ->
                          %% it finished first: the file is whole already
                          {finished, Delay, From, 0}
                  end
              end || K <- lists:seq(1, Times)],
    ct:pal("rounds (delay ms, resumed from t= ms, .part bytes after the kill): ~p", [Rounds]),
    {Code, _} = wait(element(1, start(Run(2), Dir))),
    ?assertEqual(0, Code),
    {ok, Got} = file:read_file(F),
    ?assert(Got =:= Want),
    ?assertEqual(["f.jsonl", "stderr"], ls(Dir)),
    Killed = length([R || {killed, _, _, _} = R <- Rounds]),
    Resumed = length([Ms || {_, _, Ms, _} <- Rounds, Ms =/= none]),
    ct:comment("~b of ~b kills survived, ~b runs resumed from a checkpoint", [Killed, Times, Resumed]),
    ct:pal("~b of ~b kills survived, ~b runs resumed from a checkpoint", [Killed, Times, Resumed]),
    ?assert(Killed >= 1 andalso Resumed >= 1).

%% Kill the run behind Port once F's .part holds Target bytes (and, if
%% asked, a checkpoint is there), unless it ends first: the ms it ran.
kill_at(Port, Pid, F, Target, NeedCheckpoint, T0) ->
    Ready = filelib:file_size(F ++ ".part") >= Target
        andalso (not NeedCheckpoint orelse filelib:is_regular(F ++ ".checkpoint")),
    receive
        {Port, {exit_status, _}} = Exit -> self() ! Exit, erlang:monotonic_time(millisecond) - T0
    after 0 ->
            case Ready of
                true ->
                    os:cmd("kill -KILL " ++ Pid),
                    erlang:monotonic_time(millisecond) - T0;
                false ->
                    timer:sleep(5),
                    kill_at(Port, Pid, F, Target, NeedCheckpoint, T0)
            end
    end.

%% Once the run writing F has written a frame (its .part is not empty).
wait_for_a_frame(F, Ms) when Ms > 0 ->
    case filelib:file_size(F ++ ".part") > 0 of
        true -> ok;
        false -> timer:sleep(10), wait_for_a_frame(F, Ms - 10)
    end;
wait_for_a_frame(F, _Ms) -> ct:fail({no_frame_written, F ++ ".part"}).

%% The byte offset of the checkpoint beside F (where a resumed run starts
%% writing), or 0.
checkpoint_offset(F) ->
    case file:read_file(F ++ ".checkpoint") of
        {ok, B} -> maps:get(offset, binary_to_term(B));
        {error, enoent} -> 0
    end.

%% The time of the checkpoint beside F, or none.
checkpoint_ms(F) ->
    case file:read_file(F ++ ".checkpoint") of
        {ok, B} -> maps:get(ms, binary_to_term(B));
        {error, enoent} -> none
    end.

%% Whole lines, each one a frame, but perhaps a torn last one: a kill -9
%% during a write(2) of several pages may cut it short at a page boundary
%% (rw_output), and a resumed run truncates the file to its checkpoint.
assert_lines_but_the_last(Bin) ->
    case binary:matches(Bin, <<"\n">>) of
        [] -> ok;
        Newlines ->
            {Last, 1} = lists:last(Newlines),
            assert_whole_lines(binary:part(Bin, 0, Last + 1))
    end.

%% Whole lines, each one a frame.
assert_whole_lines(<<>>) -> ok;
assert_whole_lines(Bin) ->
    ?assertEqual($\n, binary:last(Bin)),
    [{frame, _, _} = rw_frames:decode(L) || L <- binary:split(Bin, <<"\n">>, [global, trim_all])],
    ok.

%% ---------------------------------------------------------------- signals

sigterm(Config) ->
    Dir = workdir(Config, "sigterm"),
    F = filename:join(Dir, "f.jsonl"),
    Args = ["run" | timewarp_args()] ++ ["--frames", F],
    {Port, Pid} = start(Args, Dir),
    %% (a signal before the first frame names none: that case is sighup's)
    ok = wait_for_a_frame(F, 30000),
    timer:sleep(200),
    os:cmd("kill -TERM " ++ Pid),
    {Code, _} = wait(Port),
    Err = stderr(Dir),
    ct:pal("stderr: ~ts", [Err]),
    ?assertEqual(143, Code),
    {match, [Ms, Again]} = re:run(Err, "\\Arigidwarp: interrupted at t=([0-9.]+) ms; continue with: "
                                       "rigidwarp run (.*) --resume\n\\z", [{capture, all_but_first, list}]),
    ?assertEqual(string:join([A || A <- tl(Args)], " "), Again),
    ?assertNot(filelib:is_file(filename:join(Dir, "erl_crash.dump"))),
    %% the frames up to the one named are kept
    {ok, Part} = file:read_file(F ++ ".part"),
    assert_whole_lines(Part),
    {frame, Last, _} = rw_frames:decode(lists:last(binary:split(Part, <<"\n">>, [global, trim_all]))),
    ?assertEqual(Ms, rw_cli_args:format_ms(Last)),
    %% the command it gives, read by a shell, completes the run
    {0, _} = wait(element(1, start_shell("run " ++ Again ++ " --resume", Dir))),
    {ok, Want} = file:read_file(?config(timewarp_frames, Config)),
    ?assert({ok, Want} =:= file:read_file(F)),
    ?assertEqual(["f.jsonl", "stderr"], ls(Dir)).

%% SIGHUP and SIGQUIT stop a run as SIGTERM does, with their own exit
%% codes; without --frames there is nothing to resume, and the line says so.
%% SIGHUP comes once the first frame is written; the run without --frames
%% writes none to watch, so SIGQUIT comes after twice as long as the first
%% run took to its first frame.
sighup_sigquit(Config) ->
    Dir = workdir(Config, "sighup"),
    F = filename:join(Dir, "f.jsonl"),
    FirstFrameMs = interrupt(Dir, "HUP", 129, ["--frames", F], "; continue with: rigidwarp run .* --resume",
                             fun() -> ok = wait_for_a_frame(F, 30000) end),
    _ = interrupt(Dir, "QUIT", 131, [], " \\(no --frames file to resume\\)",
                  fun() -> timer:sleep(max(600, 2 * FirstFrameMs)) end),
    %% the checkpoint is there if the run got as far as one
    ?assertEqual(["f.jsonl.part", "stderr"], ls(Dir) -- ["f.jsonl.checkpoint"]).

%% A reference run stopped by signal Sig once Wait returns: its exit code
%% and line. Returns the ms from its start to the signal.
interrupt(Dir, Sig, Want, Frames, Line, Wait) ->
    T0 = erlang:monotonic_time(millisecond),
    {Port, Pid} = start(["run" | reference_args()] ++ Frames, Dir),
    ok = Wait(),
    Waited = erlang:monotonic_time(millisecond) - T0,
    os:cmd("kill -" ++ Sig ++ " " ++ Pid),
    {Code, _} = wait(Port),
    Err = stderr(Dir),
    ct:pal("~s: ~b, ~ts", [Sig, Code, Err]),
    ?assertEqual(Want, Code),
    ?assertMatch({match, _}, re:run(Err, "\\Arigidwarp: interrupted at t=[0-9.]+ ms" ++ Line ++ "\n\\z")),
    ?assertNot(filelib:is_file(filename:join(Dir, "erl_crash.dump"))),
    Waited.

sigusr1_ignored(Config) ->
    Dir = workdir(Config, "sigusr"),
    F = filename:join(Dir, "f.jsonl"),
    {Port, Pid} = start(["run" | timewarp_args()] ++ ["--frames", F], Dir),
    %% (once its handlers are set: the runtime's own answer to SIGUSR1 is a crash dump)
    ok = wait_for_a_frame(F, 30000),
    os:cmd("kill -USR1 " ++ Pid),
    timer:sleep(200),
    os:cmd("kill -USR2 " ++ Pid),
    {Code, Out} = wait(Port),
    ?assertEqual({0, <<>>}, {Code, stderr(Dir)}),
    ?assertMatch(#{<<"frames">> := 201}, jiffy:decode(Out, [return_maps])),
    ?assertNot(filelib:is_file(filename:join(Dir, "erl_crash.dump"))),
    {ok, Want} = file:read_file(?config(timewarp_frames, Config)),
    ?assert({ok, Want} =:= file:read_file(F)).

%% ---------------------------------------------------------------- outputs

frames_to_device_fifo_stdout(Config) ->
    Dir = workdir(Config, "in_place"),
    Args = ["run" | reference_args()],
    {ok, Want} = file:read_file(?config(reference_frames, Config)),
    %% a character device: written, left a device, nothing beside it
    Null = filename:join(Dir, "null"),
    sh("mknod " ++ Null ++ " c 1 3"),
    {0, _} = wait(element(1, start(Args ++ ["--frames", Null], Dir))),
    {ok, #file_info{type = device}} = file:read_link_info(Null),
    %% a FIFO: its reader gets every line, and it stays a FIFO
    Fifo = filename:join(Dir, "fifo"),
    Read = filename:join(Dir, "read.jsonl"),
    sh("mkfifo " ++ Fifo),
    Reader = open_port({spawn, "cat " ++ Fifo ++ " > " ++ Read}, [exit_status]),
    {0, _} = wait(element(1, start(Args ++ ["--frames", Fifo], Dir))),
    receive {Reader, {exit_status, 0}} -> ok after 10000 -> error(reader_did_not_finish) end,
    {ok, #file_info{type = other}} = file:read_link_info(Fifo),
    ?assert({ok, Want} =:= file:read_file(Read)),
    %% standard output: the frames, then the summary line
    {0, Out} = wait(element(1, start(Args ++ ["--frames", "-"], Dir))),
    ?assertEqual(Want, binary:part(Out, 0, byte_size(Want))),
    Lines = length(binary:matches(Want, <<"\n">>)),
    ?assertMatch(#{<<"frames">> := Lines},
                 jiffy:decode(binary:part(Out, byte_size(Want), byte_size(Out) - byte_size(Want)), [return_maps])),
    ?assertEqual(["fifo", "null", "read.jsonl", "stderr"], ls(Dir)).

%% Refused before the simulation starts: a 10 s run, answered at once.
bad_output_paths(Config) ->
    Dir = workdir(Config, "bad_paths"),
    Long = [rw_test_lib:scenario("cylinders_500.json"), "--until", "10000", "--quiet"],
    Fifo = filename:join(Dir, "fifo"),
    sh("mkfifo " ++ Fifo),
    Cases = [{["--frames", Dir], "is a directory"},
             {["--frames", filename:join([Dir, "missing", "f.jsonl"])], "missing does not exist"},
             {["--resume"], "--resume needs --frames"},
             {["--frames", "-", "--resume"], "not standard output"},
             {["--frames", Fifo, "--resume"], "not a regular file"}],
    [begin
         T0 = erlang:monotonic_time(millisecond),
         {Code, Out} = wait(element(1, start(["run" | Long] ++ Flags, Dir))),
         Wall = erlang:monotonic_time(millisecond) - T0,
         Err = stderr(Dir),
         ct:pal("~p: ~b in ~b ms: ~ts", [Flags, Code, Wall, Err]),
         ?assertEqual({2, <<>>}, {Code, Out}),
         ?assertMatch({match, _}, re:run(Err, "\\Arigidwarp: [^\n]*" ++ Problem ++ "[^\n]*\n\\z")),
         ?assert(Wall < 3000),
         ?assertEqual(["fifo", "stderr"], ls(Dir))
     end || {Flags, Problem} <- Cases],
    read_only_directory(Config, Long).

%% Root may write anywhere, so an unwritable directory is tried as nobody:
%% from a directory of its own that nobody can reach (wherever the checkout
%% is), with a copy of the escript and of the scene.
read_only_directory(_Config, [Scene | Args]) ->
    Dir = string:trim(os:cmd("mktemp -d")),
    try
        Ro = filename:join(Dir, "ro"),
        ok = file:make_dir(Ro),
        Escript = filename:join(Dir, "rigidwarp"),
        {ok, _} = file:copy(rw_test_lib:escript(), Escript),
        Copy = filename:join(Dir, "scene.json"),
        {ok, _} = file:copy(Scene, Copy),
        sh("chmod 0755 " ++ Dir ++ " " ++ Escript ++ " && chmod 0644 " ++ Copy ++ " && chmod 0555 " ++ Ro),
        Err = filename:join(Dir, "stderr"),
        Cmd = lists:flatten(["exec setpriv --reuid=nobody --regid=nogroup --clear-groups ", quote(Escript),
                             [[" ", quote(A)] || A <- ["run", Copy | Args] ++ ["--frames", filename:join(Ro, "f.jsonl")]],
                             " 2>", quote(Err)]),
        Port = open_port({spawn_executable, "/bin/sh"}, [{args, ["-c", Cmd]}, exit_status, binary, stream, {cd, Dir}]),
        {Code, _} = collect(Port, <<>>),
        {ok, Message} = file:read_file(Err),
        ct:pal("as nobody: ~b: ~ts", [Code, Message]),
        ?assertEqual(2, Code),
        ?assertMatch({match, _}, re:run(Message, "\\Arigidwarp: cannot write frames to .*/ro/f.jsonl: "
                                                 "cannot create files in directory .*/ro \\(permission denied\\)\n\\z")),
        ?assertEqual({ok, []}, file:list_dir(Ro))
    after
        _ = file:del_dir_r(Dir)
    end.

%% A device that is always full (/dev/full): the run fails with one line.
full_disk(Config) ->
    Dir = workdir(Config, "full"),
    Full = filename:join(Dir, "full"),
    sh("mknod " ++ Full ++ " c 1 7"),
    {Code, _} = wait(element(1, start(["run" | timewarp_args()] ++ ["--frames", Full], Dir))),
    Err = stderr(Dir),
    ct:pal("stderr: ~ts", [Err]),
    ?assertEqual(1, Code),
    ?assertMatch({match, _}, re:run(Err, "\\Arigidwarp: [^\n]*full[^\n]*no space left on device[^\n]*\n\\z")),
    ?assertNot(filelib:is_file(filename:join(Dir, "erl_crash.dump"))),
    ?assertEqual(["full", "stderr"], ls(Dir)).

%% ---------------------------------------------------------------- helpers

workdir(Config, Name) ->
    Dir = filename:join(?config(priv_dir, Config), Name),
    ok = file:make_dir(Dir),
    Dir.

ls(Dir) -> lists:sort(element(2, file:list_dir(Dir))).

sh(Cmd) ->
    Port = open_port({spawn, Cmd}, [exit_status, stderr_to_stdout, binary]),
    {0, _} = collect(Port, <<>>),
    ok.

stderr(Dir) ->
    {ok, Err} = file:read_file(filename:join(Dir, "stderr")),
    Err.

%% The escript started with Args in Dir (stderr to Dir/stderr): {Port, OS
%% pid}. The shell prints its pid and execs the escript, which execs the VM,
%% so the pid is the VM's.
start(Args, Dir) ->
    start_shell(lists:join(" ", [quote(A) || A <- Args]), Dir).

start_shell(ArgsText, Dir) ->
    Cmd = lists:flatten(["echo $$; exec ", quote(rw_test_lib:escript()), " ", ArgsText, " 2>",
                         quote(filename:join(Dir, "stderr"))]),
    Port = open_port({spawn_executable, "/bin/sh"}, [{args, ["-c", Cmd]}, exit_status, binary, stream, {cd, Dir}]),
    {Pid, Rest} = first_line(Port, <<>>),
    put({stdout, Port}, Rest),
    {Port, Pid}.

first_line(Port, Acc) ->
    case binary:split(Acc, <<"\n">>) of
        [Line, Rest] -> {binary_to_list(Line), Rest};
        [_] ->
            receive {Port, {data, D}} -> first_line(Port, <<Acc/binary, D/binary>>)
            after 10000 -> error(no_pid)
            end
    end.

%% {ExitStatus, Stdout}
wait(Port) ->
    Start = case erase({stdout, Port}) of undefined -> <<>>; Rest -> Rest end,
    collect(Port, Start).

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, <<Acc/binary, D/binary>>);
        {Port, {exit_status, S}} -> {S, Acc}
    after 120000 -> error(escript_timeout)
    end.

quote(S) -> "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".
