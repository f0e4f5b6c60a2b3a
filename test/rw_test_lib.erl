%% Helpers shared by the common_test suites in test/ (and by the apps'
%% EUnit tests: rebar3 compiles test/ for both).
-module(rw_test_lib).
-export([root/0, scenario/1, test_scene/1, scenes_with_reference/1, reference_frames/1, bounded_reference/1, bounded/1,
         runaway/3, check_runaways/1, escript/0, run_escript/1,
         bitwise_equal/2, assert_bitwise/2, assert_bitwise/3, first_difference/2,
         both_ways/1, awkward_double/0, awkward_vec/0]).

%% Bit for bit the same terms: =:= takes -0.0 for 0.0 on OTP 25; the
%% external format keeps each float's IEEE bits (deterministic: maps equal
%% by content encode alike, however they were built).
-spec bitwise_equal(term(), term()) -> boolean().
bitwise_equal(A, B) ->
    term_to_binary(A, [{minor_version, 2}, deterministic]) =:= term_to_binary(B, [{minor_version, 2}, deterministic]).

%% The float comparison of every test: ok when Expected and Actual are the
%% same terms bit for bit (so -0.0 is not 0.0, and 1 is not 1.0), else an
%% error naming Where (?assertBitwise in test/rw_test.hrl passes the module
%% and line), both terms (when they are small enough to read) and the path
%% to their first difference.
-spec assert_bitwise(term(), term()) -> ok.
assert_bitwise(Expected, Actual) -> assert_bitwise(Expected, Actual, undefined).

-spec assert_bitwise(term(), term(), term()) -> ok.
assert_bitwise(Expected, Actual, Where) ->
    case bitwise_equal(Expected, Actual) of
        true -> ok;
        false ->
            Shown = fun(T) -> case erts_debug:flat_size(T) < 2000 of true -> T; false -> too_large_to_show end end,
            Report = [{where, Where}, {expected, Shown(Expected)}, {value, Shown(Actual)},
                      {first_difference, first_difference(Expected, Actual)}],
            io:format(user, "~nassert_bitwise failed: ~w~n", [Report]),
            erlang:error({assert_bitwise, Report})
    end.

%% Where two terms first differ bit for bit: {Path, Expected, Actual}, Path
%% the positions (1-based, in tuples and lists) and map keys leading there,
%% or none. Printed with ~w, a -0.0 shows as -0.0.
-spec first_difference(term(), term()) -> none | {[term()], term(), term()}.
first_difference(A, B) ->
    case bitwise_equal(A, B) of
        true -> none;
        false -> diff(A, B, [])
    end.

diff(A, B, Path) when is_tuple(A), is_tuple(B), tuple_size(A) =:= tuple_size(B) ->
    diff_list(tuple_to_list(A), tuple_to_list(B), 1, Path);
diff(A, B, Path) when is_list(A), is_list(B), length(A) =:= length(B) ->
    diff_list(A, B, 1, Path);
diff(A, B, Path) when is_map(A), is_map(B), map_size(A) =:= map_size(B) ->
    Keys = lists:sort(maps:keys(A)),
    case lists:all(fun(K) -> is_map_key(K, B) end, Keys) of
        true ->
            hd([diff(maps:get(K, A), maps:get(K, B), [K | Path])
                || K <- Keys, not bitwise_equal(maps:get(K, A), maps:get(K, B))]);
        false -> {lists:reverse(Path), A, B}
    end;
diff(A, B, Path) -> {lists:reverse(Path), A, B}.

diff_list([X | As], [Y | Bs], I, Path) ->
    case bitwise_equal(X, Y) of
        true -> diff_list(As, Bs, I + 1, Path);
        false -> diff(X, Y, [I | Path])
    end.

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

%% A scene used by tests only (test/scenes/): not listed to users and not
%% compared by engine_SUITE:scenarios_equal.
-spec test_scene(string()) -> file:filename().
test_scene(Name) -> filename:join([root(), "test", "scenes", Name]).

%% Each {Name, scenario | test, UntilMs}: the scene (scenarios/ or
%% test/scenes/) loaded up to UntilMs, and its reference frames.
-spec scenes_with_reference([{string(), scenario | test, pos_integer()}]) -> [{string(), {tuple(), [tuple()]}}].
scenes_with_reference(Scenes) ->
    [begin
         File = case Where of
                    scenario -> scenario(Name ++ ".json");
                    test -> test_scene(Name ++ ".json")
                end,
         {ok, Scene} = rigidwarp:load(File, #{until => Until}),
         {Name, {Scene, reference_frames(Scene)}}
     end || {Name, Where, Until} <- Scenes].

%% The frames of the sequential reference engine, in order.
-spec reference_frames(tuple()) -> [tuple()].
reference_frames(Scene) ->
    {Frames, _Summary} = reference_run(Scene),
    Frames.

reference_run(Scene) ->
    Ref = make_ref(),
    Self = self(),
    {ok, Summary} = rw_reference:run(Scene, #{on_frame => fun(F) -> Self ! {Ref, F} end}),
    {drain(Ref), Summary}.

drain(Ref) -> receive {Ref, F} -> [F | drain(Ref)] after 0 -> [] end.

%% A random scene's reference run takes well under a second and a few MB;
%% these bounds are two orders of magnitude above.
-define(REFERENCE_MAX_MS, 30000).
-define(REFERENCE_MAX_WORDS, 100000000).

%% The reference's frames and summary of Scene, run in a process of its own
%% with bounded time and heap: a scene whose physics runs away (a sphere
%% gaining speed at every bounce sweeps ever more cells) gives an error
%% naming the bound, instead of filling the machine's memory.
-spec bounded_reference(tuple()) ->
          {ok, {[tuple()], map()}} | {error, {reference_too_slow, pos_integer()} | {reference_too_big, pos_integer()}
                                             | {reference_crashed, term()}}.
bounded_reference(Scene) ->
    case bounded(fun() -> reference_run(Scene) end) of
        {ok, _} = Ok -> Ok;
        {error, too_big} -> {error, {reference_too_big, ?REFERENCE_MAX_WORDS}};
        {error, too_slow} -> {error, {reference_too_slow, ?REFERENCE_MAX_MS}};
        {error, {crashed, Reason}} -> {error, {reference_crashed, Reason}}
    end.

%% Fun's result, from a process of its own whose heap and time are bounded
%% as the reference's (two orders of magnitude above a random scene's).
-spec bounded(fun(() -> term())) -> {ok, term()} | {error, too_big | too_slow | {crashed, term()}}.
bounded(Fun) ->
    Tag = make_ref(),
    {Pid, Mon} = spawn_opt(fun() -> exit({Tag, Fun()}) end,
                           [monitor, {max_heap_size, #{size => ?REFERENCE_MAX_WORDS, kill => true,
                                                       error_logger => false}}]),
    receive
        {'DOWN', Mon, process, Pid, {Tag, Result}} -> {ok, Result};
        {'DOWN', Mon, process, Pid, killed} -> {error, too_big};
        {'DOWN', Mon, process, Pid, Reason} -> {error, {crashed, Reason}}
    after ?REFERENCE_MAX_MS ->
        exit(Pid, kill),
        receive {'DOWN', Mon, process, Pid, _} -> ok end,
        {error, too_slow}
    end.

%% A property over random scenes records in Table (a public ETS table) a
%% scene What whose reference ran away (Why, from bounded_reference/1),
%% instead of failing there and shrinking it: each shrinking step would run
%% as long. check_runaways/1 fails after the property, naming them.
-spec runaway(ets:tid(), term(), iodata()) -> true.
runaway(Table, Why, What) -> ets:insert(Table, {{runaway, Why, erlang:unique_integer()}, What}).

-spec check_runaways(ets:tid()) -> ok.
check_runaways(Table) ->
    case [{Why, What} || {{runaway, Why, _}, What} <- ets:tab2list(Table)] of
        [] -> ok;
        Scenes ->
            [ct:pal("the reference ran away (~p) on~n~s", [Why, What]) || {Why, What} <- Scenes],
            ct:fail({runaway_scenes, length(Scenes)})
    end.

-spec escript() -> file:filename().
escript() -> filename:join([root(), "_build", "default", "bin", "rigidwarp"]).

%% Run the escript with Args from the repository root; returns
%% {ExitCode, Stdout, Stderr}.
-spec run_escript([string()]) -> {integer(), binary(), binary()}.
run_escript(Args) ->
    Dir = string:trim(os:cmd("mktemp -d")),
    ErrFile = filename:join(Dir, "stderr"),
    Cmd = lists:flatten(["exec ", quote(escript()), [[" ", quote(A)] || A <- Args], " 2>", quote(ErrFile)]),
    %% a home of its own: a run over several nodes reads or makes
    %% ~/.erlang.cookie
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, ["-c", Cmd]}, exit_status, binary, stream, {cd, root()}, {env, [{"HOME", Dir}]}]),
    {Code, Out} = collect(Port, []),
    {ok, Err} = file:read_file(ErrFile),
    _ = os:cmd("rm -rf " ++ quote(Dir)),
    {Code, Out, Err}.

quote(S) -> "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [Acc, D]);
        {Port, {exit_status, S}} -> {S, iolist_to_binary(Acc)}
    after 600000 -> error(escript_timeout)
    end.

%% Fun's result (or exception) with the engine's C loops (rw_native), and
%% with the Erlang code alone.
-spec both_ways(fun(() -> term())) -> {term(), term()}.
both_ways(Fun) ->
    Native = outcome(Fun),
    ok = rw_native:use(false),
    try
        {Native, outcome(Fun)}
    after
        ok = rw_native:use(true)
    end.

outcome(Fun) ->
    try {ok, Fun()}
    catch Class:Reason -> {Class, Reason}
    end.

%% A double that C code standing for Erlang code finds awkward, a third of
%% the time: signed zeros, subnormals (the smallest, the largest), the
%% smallest normal, near the largest double (where the Erlang code raises);
%% else any magnitude from 1e-20 to 1e20.
-spec awkward_double() -> float().
awkward_double() ->
    Specials = [0.0, -0.0, 5.0e-324, -5.0e-324, 2.225073858507201e-308, -2.2250738585072014e-308, 1.0e300, -1.0e300,
                8.98846567431158e307, 1.7976931348623157e308, -1.7976931348623157e308, 3.5, -0.25],
    case rand:uniform(3) of
        1 -> lists:nth(rand:uniform(length(Specials)), Specials);
        _ -> (rand:uniform() - 0.5) * math:pow(10.0, rand:uniform(40) - 20)
    end.

-spec awkward_vec() -> rw_vec:vec().
awkward_vec() -> {awkward_double(), awkward_double(), awkward_double()}.
