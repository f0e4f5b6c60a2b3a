%% rw_cli_args: --resume needs --frames; arguments quoted for the shell
%% read back as they were.
-module(rw_cli_args_tests).
-include_lib("eunit/include/eunit.hrl").

resume_needs_frames_test() ->
    ?assertThrow({bad_input, "--resume needs --frames" ++ _}, rw_cli_args:parse(["s.json", "--resume"])),
    ?assertMatch({"s.json", #{resume := true, frames := "f"}, false},
                 rw_cli_args:parse(["s.json", "--resume", "--frames", "f"])).

%% --speculation-mb: a whole number of MiB, 1 up to 1 TiB.
speculation_mb_test() ->
    ?assertMatch({"s.json", #{speculation_mb := 256}, false}, rw_cli_args:parse(["s.json", "--speculation-mb", "256"])),
    [?assertThrow({usage, "--speculation-mb must be " ++ _}, rw_cli_args:parse(["s.json", "--speculation-mb", V]))
     || V <- ["0", "-1", "1.5", "x", "1048577"]],
    ?assertThrow({usage, "--speculation-mb needs a value"}, rw_cli_args:parse(["s.json", "--speculation-mb"])).

shell_quote_test_() ->
    Args = ["plain/path.json", "--until", "1.5", "", "two words", "it's", "a\"b", "$HOME", "`x`", "a\\b",
            "semi;colon", "new\nline", "*", "~", "ünï"],
    [?_assertEqual(A, echo(rw_cli_args:shell_quote(A))) || A <- Args] ++
        [?_assertEqual("plain/path.json", rw_cli_args:shell_quote("plain/path.json"))].

%% What sh makes of a quoted word.
echo(Quoted) ->
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, ["-c", "printf '%s' " ++ Quoted]}, binary, exit_status, stream]),
    read(Port, <<>>).

read(Port, Acc) ->
    receive
        {Port, {data, D}} -> read(Port, <<Acc/binary, D/binary>>);
        {Port, {exit_status, 0}} -> unicode:characters_to_list(Acc)
    end.
