%% Helpers shared by the common_test suites in test/ (and by the apps'
%% EUnit tests: rebar3 compiles test/ for both).
-module(rw_test_lib).
-export([root/0, scenario/1, escript/0, run_escript/1, bitwise_equal/2]).

%% Bit for bit the same terms: =:= takes -0.0 for 0.0 on OTP 25; the
%% external format keeps each float's IEEE bits.
-spec bitwise_equal(term(), term()) -> boolean().
bitwise_equal(A, B) -> term_to_binary(A, [{minor_version, 2}]) =:= term_to_binary(B, [{minor_version, 2}]).

%% The repository root: the first directory above this file holding
%% rebar.config (suites run with the ct log directory as cwd).
-spec root() -> file:filename().
root() -> find_root(filename:dirname(filename:absname(?FILE))).

find_root("/") -> error(no_repo_root);
find_root(Dir) ->
    case filelib:is_regular(filename:join(Dir, "rebar.config")) andalso
         filelib:is_dir(filename:join(Dir, "scenarios")) of
        true -> Dir;
        false -> find_root(filename:dirname(Dir))
    end.

-spec scenario(string()) -> file:filename().
scenario(Name) -> filename:join([root(), "scenarios", Name]).

-spec escript() -> file:filename().
escript() -> filename:join([root(), "_build", "default", "bin", "rigidwarp"]).

%% Run the escript with Args from the repository root; returns
%% {ExitCode, Stdout, Stderr}.
-spec run_escript([string()]) -> {integer(), binary(), binary()}.
run_escript(Args) ->
    Dir = string:trim(os:cmd("mktemp -d")),
    ErrFile = filename:join(Dir, "stderr"),
    Cmd = lists:flatten(["exec ", quote(escript()), [[" ", quote(A)] || A <- Args], " 2>", quote(ErrFile)]),
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, ["-c", Cmd]}, exit_status, binary, stream, {cd, root()}]),
    {Code, Out} = collect(Port, []),
    {ok, Err} = file:read_file(ErrFile),
    ok = file:delete(ErrFile),
    ok = file:del_dir(Dir),
    {Code, Out, Err}.

quote(S) -> "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [Acc, D]);
        {Port, {exit_status, S}} -> {S, iolist_to_binary(Acc)}
    after 600000 -> error(escript_timeout)
    end.
