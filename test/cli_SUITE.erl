%% The rigidwarp escript as a user runs it: exit codes, stderr messages,
%% the summary as the last stdout line, frames files.
-module(cli_SUITE).
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include("rw_test.hrl").
-export([all/0, suite/0]).
-export([bench_machine/1, bench_parallelism/1, bench_scale/1, bench_scale_rounds/1]).
-export([nodes_flags/1,
         help/1, validate_every_scenario/1, summary_is_last_line/1, frames_file/1,
         bad_flags_exit_2/1, impossible_run_refused_at_once/1, integrator_and_ccd_flags/1, groups_flags/1, native_flag/1, bad_scene_exit_2/1, scenes_lists_bundled/1,
         bad_input_corpus/1,
         generated_bad_inputs/1, progress_line/1, snapshot_png/1, shell_api_rejects_bad_arguments/1,
         summary_key_order/1, version/1, scene_names/1, frames_must_match_scene/1, live_view_reports/1]).

suite() -> [{timetrap, {minutes, 5}}].

all() -> [help, version, validate_every_scenario, summary_is_last_line, frames_file, integrator_and_ccd_flags, groups_flags, native_flag,
          nodes_flags,
          bad_flags_exit_2, impossible_run_refused_at_once,
          bad_scene_exit_2, scene_names, scenes_lists_bundled, bad_input_corpus, generated_bad_inputs, progress_line,
          snapshot_png, frames_must_match_scene, live_view_reports, shell_api_rejects_bad_arguments, summary_key_order, bench_machine,
          bench_parallelism, bench_scale, bench_scale_rounds].

help(_Config) ->
    {0, Out, _} = rw_test_lib:run_escript(["help"]),
    ?assertMatch({match, _}, re:run(Out, "usage: rigidwarp")),
    {0, Out2, _} = rw_test_lib:run_escript(["run", "--help"]),
    ?assertMatch({match, _}, re:run(Out2, "--engine")),
    {2, _, Err} = rw_test_lib:run_escript([]),
    ?assertMatch({match, _}, re:run(Err, "usage")),
    %% every command has its own --help
    [begin
         {0, H, _} = rw_test_lib:run_escript([Cmd, "--help"]),
         ?assertMatch({match, _}, re:run(H, "^usage: rigidwarp " ++ Cmd))
     end || Cmd <- ["run", "validate", "scenes", "view", "snapshot", "bench"]].

%% One line, exit 0, under both spellings, and listed in the usage text.
version(_Config) ->
    _ = application:load(rigidwarp),
    {ok, Vsn} = application:get_key(rigidwarp, vsn),
    [begin
         {0, Out, Err} = rw_test_lib:run_escript([Arg]),
         ?assertEqual(<<>>, Err),
         ?assertMatch({match, _}, re:run(Out, "\\Arigidwarp [0-9][^\\n]*OTP " ++ erlang:system_info(otp_release) ++ "[^\\n]*\\n\\z")),
         ?assertMatch({match, _}, re:run(Out, "\\Arigidwarp \\Q" ++ Vsn ++ "\\E "))
     end || Arg <- ["--version", "version"]],
    {0, Usage, _} = rw_test_lib:run_escript(["help"]),
    ?assertMatch({match, _}, re:run(Usage, "\\n  version, --version ")),
    {2, <<>>, _} = rw_test_lib:run_escript(["version", "extra"]).

validate_every_scenario(_Config) ->
    Files = filelib:wildcard(filename:join([rw_test_lib:root(), "scenarios", "*.json"])),
    ?assert(length(Files) > 0),
    [{0, _, _} = rw_test_lib:run_escript(["validate", F]) || F <- Files],
    ok.

last_json_line(Out) ->
    Lines = binary:split(string:trim(Out), <<"\n">>, [global]),
    jiffy:decode(lists:last(Lines), [return_maps]).

summary_is_last_line(_Config) ->
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    Keys = [<<"scene">>, <<"engine">>, <<"bodies">>, <<"substep_ms">>, <<"stride_ms">>, <<"sim_ms">>,
            <<"wall_ms">>, <<"realtime_factor">>, <<"frames">>],
    {0, Ref, RefErr} = rw_test_lib:run_escript(["run", Scene, "--engine", "reference", "--until", "200"]),
    RefSummary = last_json_line(Ref),
    [?assert(maps:is_key(K, RefSummary)) || K <- Keys],
    ?assertMatch(#{<<"engine">> := <<"reference">>, <<"frames">> := 21, <<"sim_ms">> := 200}, RefSummary),
    ?assertMatch({match, _}, re:run(RefErr, "t=200/200 ms")),
    {0, Tw, _} = rw_test_lib:run_escript(["run", Scene, "--quiet", "--stride", "8",
                                          "--schedulers", "1", "--buckets", "3"]),
    TwSummary = last_json_line(Tw),
    [?assert(maps:is_key(K, TwSummary)) || K <- Keys ++ [<<"events">>, <<"antievents">>, <<"rollbacks">>,
                                                         <<"primary_rollbacks">>, <<"secondary_rollbacks">>,
                                                         <<"rolled_back_substeps">>, <<"efficiency">>]],
    ?assertMatch(#{<<"engine">> := <<"timewarp">>, <<"stride_ms">> := 8, <<"events">> := 1}, TwSummary).

-define(CROSS_NODE_KEYS, [cross_node_messages, cross_node_bytes, cross_node_messages_per_s, cross_node_bytes_per_s,
                          migrations]).

%% The summary's keys come in the order that `run --help` gives, the same in
%% every run, and they are the documented ones (resumed_from_ms only when a
%% run resumes).
summary_key_order(_Config) ->
    {0, Help, _} = rw_test_lib:run_escript(["run", "--help"]),
    {match, [Common, Timewarp, Reference]} =
        re:run(Help, "sorted\\):(.*?), then\\s+timewarp:(.*?);\\s+reference:(.*?)\\n(?! {20})",
               [dotall, {capture, all_but_first, list}]),
    Words = fun(Text) -> [list_to_atom(W) || W <- string:lexemes(Text, ", \n")] end,
    Doc = #{timewarp => Words(Common) ++ Words(Timewarp), reference => Words(Common) ++ Words(Reference)},
    ct:log("documented: ~p", [Doc]),
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    Keys = fun(Flags) ->
                   {0, Out, _} = rw_test_lib:run_escript(["run", Scene, "--until", "50", "--quiet" | Flags]),
                   summary_keys(Out)
           end,
    [begin
         First = Keys(["--engine", atom_to_list(Engine)]),
         ?assertEqual(First, Keys(["--engine", atom_to_list(Engine)])),
         ?assertEqual(maps:get(Engine, Doc) -- [resumed_from_ms | ?CROSS_NODE_KEYS], First)
     end || Engine <- [timewarp, reference]],
    %% over several nodes, with what they sent each other
    ?assertEqual(maps:get(timewarp, Doc) -- [resumed_from_ms], Keys(["--nodes", "2"])),
    ok.

%% The keys of the summary (the last stdout line) in the order printed.
summary_keys(Out) ->
    Lines = binary:split(string:trim(Out), <<"\n">>, [global]),
    {Props} = jiffy:decode(lists:last(Lines)),
    [binary_to_atom(K) || {K, _} <- Props].

frames_file(Config) ->
    Out = filename:join(?config(priv_dir, Config), "f.jsonl"),
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    {0, _, _} = rw_test_lib:run_escript(["run", Scene, "--until", "100", "--frame-ms", "20", "--quiet",
                                         "--frames", Out]),
    {ok, Bin} = file:read_file(Out),
    Lines = binary:split(string:trim(Bin), <<"\n">>, [global]),
    ?assertEqual([0, 20, 40, 60, 80, 100], [maps:get(<<"t">>, jiffy:decode(L, [return_maps])) || L <- Lines]),
    #{<<"bodies">> := [#{<<"id">> := <<"a">>, <<"p">> := [_, _, _], <<"v">> := VA},
                       #{<<"id">> := <<"b">>}]} = jiffy:decode(hd(Lines), [return_maps]),
    ?assertBitwise([3.0, 0.0, 0.0], VA),
    ?assertNot(filelib:is_file(Out ++ ".part")),
    %% sub-millisecond substeps and frames: times in ms, fractional where
    %% they must be, and the summary says which substep ran
    Fine = filename:join(?config(priv_dir, Config), "fine.jsonl"),
    {0, Summary, _} = rw_test_lib:run_escript(["run", Scene, "--until", "2", "--substep", "0.25",
                                               "--frame-ms", "0.5", "--quiet", "--frames", Fine]),
    ?assertBitwise(#{<<"substep_ms">> => 0.25, <<"sim_ms">> => 2, <<"frames">> => 5},
                   maps:with([<<"substep_ms">>, <<"sim_ms">>, <<"frames">>], last_json_line(Summary))),
    {ok, FineBin} = file:read_file(Fine),
    ?assertBitwise([0, 0.5, 1, 1.5, 2], [maps:get(<<"t">>, jiffy:decode(L, [return_maps]))
                                      || L <- binary:split(string:trim(FineBin), <<"\n">>, [global])]).

%% --integrator and --ccd reach the physics: Verlet follows the projectile's
%% parabola exactly where symplectic Euler does not, and both engines agree.
integrator_and_ccd_flags(Config) ->
    Scene = rw_test_lib:scenario("projectile.json"),
    Frames = fun(Name, Flags) -> element(1, run_frames(Config, Scene, "200", Name, Flags)) end,
    Default = Frames("default.jsonl", []),
    Verlet = Frames("verlet.jsonl", ["--integrator", "verlet", "--ccd", "on"]),
    ?assertEqual(Verlet, Frames("verlet-ref.jsonl", ["--integrator", "verlet", "--ccd", "on", "--engine", "reference"])),
    ?assertNotEqual(Default, Verlet).

%% --groups and --group-max change which processes compute the bodies, never
%% the frames: Cylinders 200 lands on its posts at about 600 ms, and its
%% bodies are grouped soon after.
groups_flags(Config) ->
    Scene = rw_test_lib:scenario("cylinders_200.json"),
    Run = fun(Name, Flags) ->
                  {Bin, Stdout} = run_frames(Config, Scene, "800", Name, Flags),
                  {Bin, last_json_line(Stdout)}
          end,
    {Default, #{<<"regroups">> := Regroups}} = Run("default.jsonl", []),
    {Alone, #{<<"regroups">> := 0}} = Run("alone.jsonl", ["--groups", "off"]),
    {Pairs, #{<<"regroups">> := PairRegroups}} = Run("pairs.jsonl", ["--groups", "on", "--group-max", "2"]),
    ?assert(Regroups > 0 andalso PairRegroups > 0),
    ?assertEqual(Default, Alone),
    ?assertEqual(Default, Pairs).

%% --native off runs the engine's Erlang code alone: the same frames file,
%% and the summary says which ran.
native_flag(Config) ->
    Scene = rw_test_lib:test_scene("pile_40.json"),
    Run = fun(Name, Flags) ->
                  {Bin, Stdout} = run_frames(Config, Scene, "400", Name, Flags),
                  {Bin, last_json_line(Stdout)}
          end,
    {Default, #{<<"native">> := true}} = Run("default.jsonl", []),
    {On, #{<<"native">> := true}} = Run("on.jsonl", ["--native", "on"]),
    {Off, #{<<"native">> := false}} = Run("off.jsonl", ["--native", "off"]),
    ?assertEqual(Default, On),
    ?assertEqual(Default, Off).

%% --nodes 2 and 3 write the reference's frames file, and say what crossed
%% between the nodes; a node that cannot be reached is one line and exit 1.
nodes_flags(Config) ->
    Scene = rw_test_lib:scenario("bouncing_200_400.json"),
    {Reference, _} = run_frames(Config, Scene, "400", "reference.jsonl", ["--engine", "reference"]),
    [begin
         {Frames, Stdout} = run_frames(Config, Scene, "400", "nodes.jsonl", ["--nodes", N]),
         ?assertEqual(Reference, Frames),
         #{<<"nodes">> := Nodes, <<"cross_node_messages">> := Messages} = last_json_line(Stdout),
         ?assertEqual(list_to_integer(N), Nodes),
         ?assert(Messages > 0)
     end || N <- ["2", "3"]],
    {1, Out, Err} = rw_test_lib:run_escript(["run", Scene, "--until", "50", "--quiet",
                                             "--connect", "nobody_here@127.0.0.1", "--cookie", "x"]),
    ?assertEqual(<<>>, Out),
    ?assertMatch({match, _}, re:run(Err, "\\Arigidwarp: cannot connect to node nobody_here@127.0.0.1[^\\n]*\\n\\z")).

%% Run Scene until UntilMs with Flags (exit 0), its frames to Name in the
%% test's directory: {Frames, Stdout}.
run_frames(Config, Scene, UntilMs, Name, Flags) ->
    Out = filename:join(?config(priv_dir, Config), Name),
    {0, Stdout, _} = rw_test_lib:run_escript(["run", Scene, "--until", UntilMs, "--quiet", "--frames", Out | Flags]),
    {ok, Bin} = file:read_file(Out),
    {Bin, Stdout}.

bad_flags_exit_2(_Config) ->
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    Cases = [{["run", Scene, "--bogus"], "unknown flag --bogus"},
             {["run", Scene, "--until", "abc"], "--until must be a positive number of ms"},
             {["run", Scene, "--stride", "-5"], "--stride must be a positive number of ms"},
             {["run", Scene, "--engine", "warp"], "--engine must be timewarp or reference"},
             {["run", Scene, "--integrator", "rk4"], "--integrator must be one of symplectic_euler, verlet, explicit_euler"},
             {["run", Scene, "--ccd", "yes"], "--ccd must be on or off, got yes"},
             {["run", Scene, "--ccd"], "--ccd needs a value"},
             {["run", Scene, "--groups", "sometimes"], "--groups must be on or off, got sometimes"},
             {["run", Scene, "--group-max", "0"], "--group-max must be a positive integer, got 0"},
             {["run", Scene, "--group-max", "4097"], "--group-max must be at most 4096, got 4097"},
             {["run", Scene, "--native", "yes"], "--native must be on or off, got yes"},
             {["run", Scene, "--native"], "--native needs a value"},
             {["run", Scene, "--nodes", "0"], "--nodes must be a positive integer, got 0"},
             {["run", Scene, "--nodes", "65"], "--nodes must be at most 64, got 65"},
             {["run", Scene, "--connect", "nohost"], "--connect takes node names as name@host"},
             {["run", Scene, "--cookie", "secret"], "--cookie goes with --connect"},
             {["run", Scene, "--nodes", "2", "--connect", "a@b"], "--nodes and --connect do not go together"},
             {["run", Scene, "--schedulers", "999"], "--schedulers must be at most"},
             {["run", Scene, "--until"], "--until needs a value"},
             {["run"], "run needs a scene file"},
             {["frobnicate"], "unknown command frobnicate"},
             {["run", Scene, "--substep", "3"], "not a multiple of the substep"},
             {["run", Scene, "--until", "0"], "--until must be a positive number of ms"},
             {["run", Scene, "--until", "1e3"], "--until must be a positive number of ms"},
             {["run", Scene, "--until", "99999999999999999999999"], "--until must be a positive number of ms"},
             {["run", Scene, "--buckets", "-1"], "--buckets must be a positive integer, got -1"},
             {["run", Scene, "--schedulers", "two"], "--schedulers must be a positive integer"},
             {["run", Scene, Scene], "unexpected argument"},
             {["validate"], "validate takes exactly one scene file"},
             {["scenes", "a", "b"], "scenes takes at most one directory"},
             {["view", "f.jsonl"], "view needs --scene"},
             {["view", "f.jsonl", "--scene", Scene, "--port", "http"], "--port must be a port number"},
             {["view", "--live", Scene, "--engine", "reference"], "view --live runs the timewarp engine only"},
             {["snapshot", "f.jsonl", "--scene", Scene, "--out", "x.png"], "snapshot needs --at MS"},
             {["snapshot", "f.jsonl", "--scene", Scene, "--at", "5"], "snapshot needs --out"},
             {["snapshot", "f.jsonl", "--scene", Scene, "--at", "-5", "--out", "x.png"], "--at must be a non-negative"},
             {["snapshot", "f.jsonl", "--scene", Scene, "--at", "5", "--out", "x.jpg"], "--out must name a .png"},
             {["snapshot", "missing.jsonl", "--scene", Scene, "--at", "5", "--out", "x.png"], "cannot read frames file"},
             {["bench"], "bench needs a benchmark: accuracy"},
             {["bench", "speed"], "unknown benchmark speed"},
             {["bench", "accuracy", "--bogus"], "unknown flag --bogus"},
             {["bench", "accuracy", "--substeps", "1,0"], "--substeps must be a positive number of ms"},
             {["bench", "accuracy", "--substeps", "1,,2"], "--substeps takes a comma-separated list"},
             {["bench", "accuracy", "--ccd", "maybe"], "--ccd takes off, on or off,on"},
             {["bench", "accuracy", "--integrators", "rk4"], "--integrators: unknown integrator rk4"},
             {["bench", "accuracy", "--out", "a.txt"], "--out must name a .csv file"},
             {["bench", "accuracy", "--plot"], "--plot needs a value"},
             {["bench", "accuracy", "--scenes", "projectile:soon"], "--scenes projectile: must be a positive number of ms"},
             {["bench", "accuracy", "--scenes", "no_such_scene"], "no_such_scene: no such scene"},
             {["bench", "accuracy", "--scenes", "scenarios/no_such_scene.json"],
              "scenarios/no_such_scene.json: $: cannot read file"},
             {["bench", "accuracy", "--scenes", "cylinders_200"], "cylinders_200: the exact solver models spheres"},
             {["bench", "machine", "--repeats", "0"], "--repeats must be a positive integer, got 0"},
             {["bench", "machine", "--fast"], "bench machine takes only --repeats N"},
             {["bench", "speed"], "unknown benchmark speed (known: accuracy, machine, parallelism, scale)"},
             {["bench", "scale", "--counts", "10,x"], "--counts must be a positive integer, got x"},
             {["bench", "scale", "extra"], "unexpected argument extra"},
             {["bench", "scale", "--rounds", "0"], "--rounds must be a positive integer, got 0"},
             {["bench", "scale", "--counts", "500,20,500"], "--counts names 500 twice"},
             {["bench", "parallelism", "--until", "0"], "--until must be a positive number of ms"},
             {["bench", "parallelism", "--repeats", "x"], "--repeats must be a positive integer, got x"},
             {["bench", "parallelism", "--fast"], "unknown flag --fast"},
             {["bench", "parallelism", "no_such_scene"], "no_such_scene: no such scene"},
             %% a newline in an argument is shown escaped: every message is one line
             {["run", "two\nlines"], "two\\nlines: no such scene"},
             {["run", "two\nlines.json"], "two\\nlines.json: $: cannot read file"},
             {["run", Scene, "--until", "1\n2"], "--until must be a positive number of ms (such as 2 or 0.5), got 1\\n2"},
             {["view", "f.jsonl", "--scene", "bad\tname"], "bad\\tname: no such scene"}],
    [begin
         {Code, Out, Err} = rw_test_lib:run_escript(Args),
         ct:log("~p -> ~b~n~s", [Args, Code, Err]),
         ?assertEqual(2, Code),
         ?assertEqual(<<>>, Out),
         ?assertMatch([_], binary:split(string:trim(Err), <<"\n">>, [global])),
         ?assertMatch({match, _}, re:run(Err, "\\Q" ++ Expect ++ "\\E"))
     end || {Args, Expect} <- Cases],
    ok.

%% More buckets than the VM has processes for, and an empty frames path:
%% refused before anything starts (exit 2 within seconds, one line), and
%% nothing is written where the run was started.
impossible_run_refused_at_once(Config) ->
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    Cases = [{"buckets", ["--buckets", "300000", "--frames", "f.jsonl"],
              "rigidwarp: bad value for option buckets: 300000 buckets and 2 bodies need 300002 processes, more than "
              "this VM's process limit of"},
             {"frames", ["--frames", ""], "rigidwarp: cannot write frames to an empty path"}],
    [begin
         Cwd = filename:join(?config(priv_dir, Config), Name),
         ok = file:make_dir(Cwd),
         T0 = erlang:monotonic_time(millisecond),
         {Code, Out, Err} = run_escript_in(Cwd, ["run", Scene | Flags], 30),
         Ms = erlang:monotonic_time(millisecond) - T0,
         ct:log("~p -> ~b in ~b ms~n~s", [Flags, Code, Ms, Err]),
         ?assertEqual({2, <<>>}, {Code, Out}),
         ?assertMatch([_], binary:split(string:trim(Err), <<"\n">>, [global])),
         ?assertMatch({match, _}, re:run(Err, "^\\Q" ++ Expect ++ "\\E")),
         ?assert(Ms < 10000),
         ?assertEqual({ok, []}, file:list_dir(Cwd))
     end || {Name, Flags, Expect} <- Cases],
    ok.

bad_scene_exit_2(Config) ->
    Dir = ?config(priv_dir, Config),
    Write = fun(Name, Text) -> P = filename:join(Dir, Name), ok = file:write_file(P, Text), P end,
    Cases = [{Write("trunc.json", "{\"name\": \"x\""), "invalid JSON"},
             {Write("neg.json", "{\"name\":\"x\",\"duration_ms\":10,\"bodies\":[{\"id\":\"a\",\"shape\":\"sphere\","
                                 "\"radius\":-1,\"mass\":1,\"position\":[0,0,0]}]}"), "$.bodies[0].radius: must be positive"},
             {filename:join(Dir, "missing.json"), "cannot read file"}],
    [begin
         Frames = filename:join(Dir, "never.jsonl"),
         {Code, Out, Err} = rw_test_lib:run_escript(["run", File, "--frames", Frames]),
         ?assertEqual(2, Code),
         ?assertEqual(<<>>, Out),
         ?assertEqual(1, length(binary:split(string:trim(Err), <<"\n">>, [global]))),
         ?assertMatch({match, _}, re:run(Err, "\\Q" ++ Expect ++ "\\E")),
         ?assertNot(filelib:is_file(Frames)),
         {2, _, _} = rw_test_lib:run_escript(["validate", File])
     end || {File, Expect} <- Cases],
    ok.

%% A scene NAME is scenarios/NAME.json: here, or in the checkout of the
%% escript when run elsewhere; an unknown name says where it looked.
scene_names(Config) ->
    Dir = ?config(priv_dir, Config),
    Frames = fun(Cwd, Scene, Name) ->
                     Out = filename:join(Dir, Name),
                     {0, _, _} = run_escript_in(Cwd, ["run", Scene, "--until", "100", "--quiet", "--frames", Out], 120),
                     {ok, Bin} = file:read_file(Out),
                     Bin
             end,
    ByPath = Frames(rw_test_lib:root(), "scenarios/bouncing_50_250.json", "path.jsonl"),
    ?assertEqual(ByPath, Frames(rw_test_lib:root(), "bouncing_50_250", "name.jsonl")),
    ?assertEqual(ByPath, Frames(Dir, "bouncing_50_250", "elsewhere.jsonl")),
    {0, <<"scenarios/projectile.json: ok\n">>, _} = rw_test_lib:run_escript(["validate", "projectile"]),
    Elsewhere = list_to_binary(rw_test_lib:scenario("projectile.json") ++ ": ok\n"),
    {0, Elsewhere, _} = run_escript_in(Dir, ["validate", "projectile"], 60),
    %% a name close to some: one line naming the places and the nearest names
    [begin
         {Code, Out, Err} = rw_test_lib:run_escript(Args),
         ct:log("~p -> ~b~n~s", [Args, Code, Err]),
         ?assertEqual({2, <<>>}, {Code, Out}),
         ?assertMatch([_], binary:split(string:trim(Err), <<"\n">>, [global])),
         ?assertMatch({match, _}, re:run(Err, "^rigidwarp: bouncing_200: no such scene \\(looked for bouncing_200, "
                                              "scenarios/bouncing_200.json\\); closest: bouncing_200_100, "
                                              "bouncing_200_250, bouncing_200_400"))
     end || Args <- [["run", "bouncing_200"], ["validate", "bouncing_200"]]],
    {2, <<>>, Far} = run_escript_in(Dir, ["run", "no_such_scene"], 60),
    ?assertMatch({match, _}, re:run(Far, "\\Qrigidwarp: no_such_scene: no such scene (looked for no_such_scene, "
                                         "scenarios/no_such_scene.json, " ++ rw_test_lib:scenario("no_such_scene.json")
                                         ++ ")\\E; rigidwarp scenes lists the scenes\\n\\z")).

%% Every scene's entry: a line with its file, bodies, duration and start
%% box, then its whole description indented; the Bouncing scenes differ.
scenes_lists_bundled(_Config) ->
    {0, Out, _} = rw_test_lib:run_escript(["scenes"]),
    ct:log("~s", [Out]),
    Lines = binary:split(string:trim(Out, trailing), <<"\n">>, [global]),
    [?assert(string:length(L) =< 100) || L <- Lines],
    Entries = entries(Lines),
    Files = [filename:basename(F) || F <- filelib:wildcard(filename:join([rw_test_lib:root(), "scenarios", "*.json"]))],
    ?assertEqual(lists:sort(Files), lists:sort([binary_to_list(F) || {F, _, _} <- Entries])),
    [begin
         {ok, Bin} = file:read_file(rw_test_lib:scenario(binary_to_list(F))),
         #{<<"description">> := D} = jiffy:decode(Bin, [return_maps]),
         ?assertEqual(lists:join(" ", string:lexemes(D, " ")), lists:join(" ", Desc))
     end || {F, _, Desc} <- Entries],
    Head = fun(F) -> {F, H, _} = lists:keyfind(F, 1, Entries), H end,
    ?assertMatch({match, _}, re:run(Head(<<"head_on_elastic.json">>), "^ +2 bodies +1000 ms  in \\[-?[0-9.]+,")),
    [?assertMatch({match, _}, re:run(Head(F), "^ +1 body +[0-9]+ ms  at \\[[-0-9.]+,[-0-9.]+,[-0-9.]+\\]$"))
     || F <- [<<"projectile.json">>, <<"ball_drop.json">>, <<"fast_thin_wall.json">>]],
    Bouncing = [H || {<<"bouncing_", _/binary>>, H, _} <- Entries],
    ?assert(length(Bouncing) >= 7),
    ?assertEqual(length(Bouncing), length(lists:usort(Bouncing))).

%% The scene list as {File, RestOfFirstLine, DescriptionWords}.
entries([]) -> [];
entries([First | Rest]) ->
    {Desc, More} = lists:splitwith(fun(<<"    ", _/binary>>) -> true; (_) -> false end, Rest),
    [File, Head] = binary:split(First, <<" ">>),
    [{File, Head, lists:append([string:lexemes(D, " ") || D <- Desc])} | entries(More)].

%% run_escript/1 from Cwd (with Env), stopped after TimeoutS seconds (exit 124).
run_escript_in(Cwd, Args, TimeoutS) -> run_escript_in(Cwd, [], Args, TimeoutS).

run_escript_in(Cwd, Env, Args, TimeoutS) ->
    Err = filename:join(string:trim(os:cmd("mktemp -d")), "stderr"),
    Cmd = lists:flatten(["exec ", os:find_executable("timeout"), " ", integer_to_list(TimeoutS), " ",
                         sh_quote(rw_test_lib:escript()), [[" ", sh_quote(A)] || A <- Args], " 2>", sh_quote(Err)]),
    Port = open_port({spawn_executable, "/bin/sh"}, [{args, ["-c", Cmd]}, {env, Env}, exit_status, binary, stream,
                                                     {cd, Cwd}]),
    {Code, Out} = collect(Port, []),
    {ok, ErrBin} = file:read_file(Err),
    ok = file:del_dir_r(filename:dirname(Err)),
    {Code, Out, ErrBin}.

sh_quote(S) -> "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [Acc, D]);
        {Port, {exit_status, S}} -> {S, iolist_to_binary(Acc)}
    end.

%%% The bad-input corpus (test/bad_input): for each broken scene, exit code
%%% 2, one line on stderr with the JSON path and the problem, nothing on
%%% stdout, no frames file (not even a partial one).

bad_input_corpus(Config) ->
    Dir = filename:join(rw_test_lib:root(), "test/bad_input"),
    {ok, Expected} = file:consult(filename:join(Dir, "expected.terms")),
    Files = [filename:basename(F) || F <- filelib:wildcard(filename:join(Dir, "*.json"))],
    ?assertEqual(lists:sort(Files), lists:sort([F || {F, _} <- Expected])),
    ?assert(length(Files) >= 40),
    [expect_rejected(filename:join(Dir, F), Msg, Config) || {F, Msg} <- Expected],
    ok.

expect_rejected(File, Msg, Config) ->
    Frames = filename:join(?config(priv_dir, Config), "never.jsonl"),
    {Code, Out, Err} = rw_test_lib:run_escript(["run", File, "--frames", Frames]),
    ct:log("~s -> ~b~n~s", [File, Code, Err]),
    ?assertEqual(2, Code),
    ?assertEqual(<<>>, Out),
    ?assertEqual([unicode:characters_to_binary(["rigidwarp: ", File, ": ", Msg])],
                 [binary:part(L, 0, min(byte_size(L), byte_size(unicode:characters_to_binary(["rigidwarp: ", File, ": ", Msg]))))
                  || L <- binary:split(string:trim(Err), <<"\n">>, [global])]),
    ?assertNot(filelib:is_file(Frames)),
    ?assertNot(filelib:is_file(Frames ++ ".part")).

%% Inputs too big or too odd to commit: made here.
generated_bad_inputs(Config) ->
    Dir = ?config(priv_dir, Config),
    Big = filename:join(Dir, "big.json"),
    {ok, Fd} = file:open(Big, [write, raw]),
    ok = file:write(Fd, "{\"name\": \""),
    Chunk = binary:copy(<<"x">>, 1024 * 1024),
    [ok = file:write(Fd, Chunk) || _ <- lists:seq(1, 100)],
    ok = file:write(Fd, "\"}"),
    ok = file:close(Fd),
    Garbage = filename:join(Dir, "garbage.json"),
    ok = file:write_file(Garbage, crypto:strong_rand_bytes(4096)),
    Nul = filename:join(Dir, "nul.json"),
    ok = file:write_file(Nul, <<"{\"name\": \"a\", \"duration_ms\": 1", 0, "0}">>),
    Latin1 = filename:join(Dir, "latin1.json"),
    ok = file:write_file(Latin1, <<"{\"name\": \"caf", 16#E9, "\", \"duration_ms\": 10}">>),
    Cases = [{Big, "$: file is larger than 64 MiB"},
             {Garbage, "$: invalid JSON at line "},
             {Nul, "$: invalid JSON at line 1, column 31: unexpected byte 0x00"},
             {Latin1, "$: invalid JSON at line 1"},
             {Dir, "$: cannot read file"}],
    [expect_rejected(F, Msg, Config) || {F, Msg} <- Cases],
    ok = file:delete(Big).

%% Not a terminal here: plain progress lines on stderr, with the Time Warp
%% numbers; --quiet silences them; the summary stays the last stdout line.
progress_line(_Config) ->
    Scene = rw_test_lib:scenario("bouncing_50_250.json"),
    {0, Out, Err} = rw_test_lib:run_escript(["run", Scene, "--until", "500", "--schedulers", "1"]),
    Lines = binary:split(string:trim(Err), <<"\n">>, [global]),
    ct:log("~s", [Err]),
    [?assertMatch({match, _}, re:run(L, "^rigidwarp: t=[0-9]+/500 ms  realtime x[0-9.]+  GVT lag [0-9]+ ms  "
                                        "rollbacks [0-9]+")) || L <- Lines],
    ?assertMatch({match, _}, re:run(lists:last(Lines), "t=500/500 ms.*ETA 0.0 s")),
    ?assertNotEqual(nomatch, binary:match(Out, <<"\"engine\":\"timewarp\"">>)),
    {0, _, <<>>} = rw_test_lib:run_escript(["run", Scene, "--until", "100", "--quiet"]).

snapshot_png(Config) ->
    Dir = ?config(priv_dir, Config),
    Scene = rw_test_lib:scenario("newtons_cradle.json"),
    Frames = filename:join(Dir, "cradle.jsonl"),
    Png = filename:join(Dir, "cradle.png"),
    {0, _, _} = rw_test_lib:run_escript(["run", Scene, "--until", "300", "--quiet", "--frames", Frames]),
    {0, Out, _} = rw_test_lib:run_escript(["snapshot", Frames, "--scene", Scene, "--at", "250", "--out", Png]),
    ?assertEqual(list_to_binary(Png), string:trim(Out)),
    {ok, <<137, "PNG", _/binary>> = Bin} = file:read_file(Png),
    ?assert(byte_size(Bin) > 5000),
    %% a frames file with a broken line names the line
    ok = file:write_file(Frames, <<"{\"t\":0,\"bodies\":[]}\nnot json\n">>),
    {2, _, Err} = rw_test_lib:run_escript(["snapshot", Frames, "--scene", Scene, "--at", "0", "--out", Png]),
    ?assertMatch({match, _}, re:run(Err, ":2: not a frame line")).

%% Frames shown with a scene that did not make them, and --at outside the
%% file's times, are refused at once: exit 2, one line, no server started,
%% no gnuplot needed (it is off the PATH here).
frames_must_match_scene(Config) ->
    Dir = ?config(priv_dir, Config),
    Frames = fun(Scene, Name, Flags) ->
                     Out = filename:join(Dir, Name),
                     {0, _, _} = rw_test_lib:run_escript(["run", Scene, "--quiet", "--frames", Out | Flags]),
                     Out
             end,
    HeadOn = rw_test_lib:scenario("head_on_elastic.json"),
    NewtonsCradle = rw_test_lib:scenario("newtons_cradle.json"),
    Head = Frames(HeadOn, "head.jsonl", ["--until", "300"]),
    Cradle = Frames(NewtonsCradle, "cradle.jsonl", ["--until", "300"]),
    {ok, HeadBin} = file:read_file(Head),
    [First | _] = binary:split(HeadBin, <<"\n">>, [global]),
    #{<<"bodies">> := [A, _]} = FirstFrame = jiffy:decode(First, [return_maps]),
    OneBody = filename:join(Dir, "one.jsonl"),
    ok = file:write_file(OneBody, [jiffy:encode(FirstFrame#{<<"bodies">> := [A]}), $\n, HeadBin]),
    Twice = filename:join(Dir, "twice.jsonl"),
    ok = file:write_file(Twice, [jiffy:encode(FirstFrame#{<<"bodies">> := [A, A]}), $\n]),
    Png = filename:join(Dir, "never.png"),
    Path = no_gnuplot_path(Dir),
    Cases = [{["view", Head, "--scene", NewtonsCradle, "--port", "0"],
              Head ++ ": body a in the frame at t=0 ms is not a dynamic body of " ++ NewtonsCradle ++
              " (the frame has 2 bodies, the scene 5): frames of another scene?"},
             {["snapshot", Cradle, "--scene", HeadOn, "--at", "100", "--out", Png],
              Cradle ++ ": body b0 in the frame at t=0 ms is not a dynamic body of " ++ HeadOn ++
              " (the frame has 5 bodies, the scene 2)"},
             {["view", OneBody, "--scene", HeadOn, "--port", "0"],
              OneBody ++ ": the frame at t=0 ms has 1 body, " ++ HeadOn ++ " has 2 bodies"},
             {["snapshot", Twice, "--scene", HeadOn, "--at", "0", "--out", Png],
              Twice ++ ": the frame at t=0 ms lacks body b of " ++ HeadOn},
             {["snapshot", Head, "--scene", HeadOn, "--at", "99999", "--out", Png],
              "--at 99999 is outside the times of " ++ Head ++ ": 0..300 ms"},
             {["view", Head, "--scene", "newtons_cradle", "--port", "0"],
              Head ++ ": body a in the frame at t=0 ms is not a dynamic body of scenarios/newtons_cradle.json"},
             {["view", Head, "--scene", "no_such_scene", "--port", "0"], "no_such_scene: no such scene"}],
    [begin
         T0 = erlang:monotonic_time(millisecond),
         {Code, Out, Err} = run_escript_in(rw_test_lib:root(), [{"PATH", Path}], Args, 30),
         Ms = erlang:monotonic_time(millisecond) - T0,
         ct:log("~p -> ~b in ~b ms~n~s", [Args, Code, Ms, Err]),
         ?assertEqual({2, <<>>}, {Code, Out}),
         ?assertMatch([_], binary:split(string:trim(Err), <<"\n">>, [global])),
         ?assertMatch({match, _}, re:run(Err, "^rigidwarp: \\Q" ++ Expect ++ "\\E")),
         ?assert(Ms < 10000)
     end || {Args, Expect} <- Cases],
    ?assertNot(filelib:is_file(Png)),
    %% the frames of a scene with a time inside the file are fine (and gnuplot is missing)
    {1, <<>>, NoGnuplot} = run_escript_in(rw_test_lib:root(), [{"PATH", Path}],
                                          ["snapshot", Head, "--scene", HeadOn, "--at", "300", "--out", Png], 30),
    ?assertMatch({match, _}, re:run(NoGnuplot, "snapshot needs gnuplot")).

%% A directory for PATH with what the escript needs and no gnuplot.
no_gnuplot_path(Dir) ->
    Bin = filename:join(Dir, "bin"),
    ok = filelib:ensure_dir(filename:join(Bin, "x")),
    [begin
         Link = filename:join(Bin, Cmd),
         _ = file:delete(Link),
         ok = file:make_symlink(os:find_executable(Cmd), Link)
     end || Cmd <- ["escript", "erl", "dirname", "basename", "sed"]],
    Bin.

%% view --live: run's progress line on stderr, run's summary on stdout when
%% the run ends (keys in run's order), and the viewer serves on after it.
live_view_reports(Config) ->
    ErrFile = filename:join(?config(priv_dir, Config), "live.stderr"),
    Cmd = lists:flatten(["exec ", sh_quote(rw_test_lib:escript()), " view --live ",
                         sh_quote(rw_test_lib:scenario("head_on_elastic.json")), " --until 500 --port 0 2>",
                         sh_quote(ErrFile)]),
    Port = open_port({spawn_executable, "/bin/sh"}, [{args, ["-c", Cmd]}, {line, 1 bsl 16}, binary, exit_status,
                                                     {cd, rw_test_lib:root()}]),
    {os_pid, OsPid} = erlang:port_info(Port, os_pid),
    try
        [Url, Summary] = read_lines(Port, 2),
        {match, [PortNum]} = re:run(Url, "^http://127.0.0.1:([0-9]+)/$", [{capture, all_but_first, list}]),
        {0, Run, _} = rw_test_lib:run_escript(["run", rw_test_lib:scenario("head_on_elastic.json"), "--until", "500",
                                                "--quiet"]),
        ?assertEqual(summary_keys(Run), summary_keys(Summary)),
        ?assertMatch(#{<<"scene">> := <<"head_on_elastic">>, <<"engine">> := <<"timewarp">>, <<"bodies">> := 2,
                       <<"sim_ms">> := 500, <<"frames">> := 51, <<"committed_substeps">> := 1000},
                     jiffy:decode(Summary, [return_maps])),
        {ok, Sock} = gen_tcp:connect("127.0.0.1", list_to_integer(PortNum), [binary, {active, false}], 5000),
        ok = gen_tcp:close(Sock),
        {ok, Err} = file:read_file(ErrFile),
        ct:log("~s~n~s", [Summary, Err]),
        [Viewer | Progress] = binary:split(string:trim(Err), <<"\n">>, [global]),
        ?assertMatch({match, _}, re:run(Viewer, "^rigidwarp: viewer at http")),
        ?assertNotEqual([], Progress),
        [?assertMatch({match, _}, re:run(L, "^rigidwarp: t=[0-9]+/500 ms  realtime x[0-9.]+  GVT lag [0-9]+ ms  "
                                            "rollbacks [0-9]+")) || L <- Progress],
        ?assertMatch({match, _}, re:run(lists:last(Progress), "t=500/500 ms.*ETA 0.0 s"))
    after
        os:cmd("kill " ++ integer_to_list(OsPid)),
        receive {Port, {exit_status, _}} -> ok after 10000 -> ok end
    end.

read_lines(_Port, 0) -> [];
read_lines(Port, N) ->
    receive
        {Port, {data, {eol, Line}}} -> [Line | read_lines(Port, N - 1)];
        {Port, {exit_status, S}} -> error({exited, S})
    after 60000 -> error(no_line)
    end.

%% The shell API answers bad arguments with {error, Message}, starting nothing.
shell_api_rejects_bad_arguments(_Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    Before = supervisor:which_children(rw_sims_sup),
    Cases = [{fun() -> rigidwarp:run(some_atom, #{}) end, "the scene file must be a string"},
             {fun() -> rigidwarp:run(Scene, #{untill => 5}) end, "unknown option untill"},
             {fun() -> rigidwarp:run(Scene, #{until => -5}) end, "bad value for option until"},
             {fun() -> rigidwarp:run(Scene, #{integrator => rk4}) end, "bad value for option integrator: rk4"},
             {fun() -> rigidwarp:run(Scene, #{ccd => yes}) end, "bad value for option ccd"},
             {fun() -> rigidwarp:run(Scene, #{groups => maybe}) end, "bad value for option groups"},
             {fun() -> rigidwarp:run(Scene, #{group_max => 0}) end, "bad value for option group_max"},
             {fun() -> rigidwarp:run(Scene, not_a_map) end, "options must be a map"},
             {fun() -> rigidwarp:start(Scene, #{engine => reference}) end, "timewarp engine only"},
             {fun() -> rigidwarp:start("/nonexistent.json", #{}) end, "cannot read file"},
             {fun() -> rigidwarp:run(Scene, #{buckets => 300000}) end,
              "bad value for option buckets: 300000 buckets and 2 bodies need 300002 processes"},
             {fun() -> rigidwarp:start(Scene, #{buckets => 300000}) end,
              "bad value for option buckets: 300000 buckets and 2 bodies need 300002 processes"},
             {fun() -> rigidwarp:run(Scene, #{frames => ""}) end, "cannot write frames to an empty path"},
             {fun() -> rigidwarp:frames(not_a_sim) end, "not a simulation"},
             {fun() -> rigidwarp:stats(#{}) end, "not a simulation"}],
    [begin
         {error, Msg} = F(),
         ?assertMatch({match, _}, re:run(Msg, "\\Q" ++ Expect ++ "\\E"))
     end || {F, Expect} <- Cases],
    ?assertEqual(Before, supervisor:which_children(rw_sims_sup)).

%% The parallelism projection of a scene: a table row and a JSON line whose
%% figures hold together (a speedup is at most the core count and the
%% average parallelism, and grows with the cores).
bench_parallelism(_Config) ->
    {0, Out, _} = rw_test_lib:run_escript(["bench", "parallelism", "bouncing_50_250", "--until", "200",
                                           "--repeats", "1"]),
    ?assertMatch({match, _}, re:run(Out, "\\| bouncing_50_250 \\| [0-9]+ \\|")),
    #{<<"until_ms">> := 200, <<"scenes">> := [#{<<"scene">> := <<"bouncing_50_250">>, <<"work">> := Work,
                                                 <<"critical_path">> := Path, <<"parallelism">> := Par,
                                                 <<"projected">> := Projected, <<"measured_1_to_2">> := Measured}]} =
        last_json_line(Out),
    ?assert(0 < Path andalso Path =< Work),
    ?assertEqual([<<"16">>, <<"2">>, <<"4">>, <<"64">>, <<"8">>], lists:sort(maps:keys(Projected))),
    Speedups = [maps:get(integer_to_binary(P), Projected) || P <- [2, 4, 8, 16, 64]],
    ?assertEqual(Speedups, lists:sort(Speedups)),
    [?assert(S =< P + 1.0e-9 andalso S =< Par + 1.0e-9) || {P, S} <- lists:zip([2, 4, 8, 16, 64], Speedups)],
    ?assert(Measured > 0).

%% Gases of growing size: a row each, the first the measure of the others,
%% and memory per body at three points of the run.
bench_scale(_Config) ->
    {0, Out, Err} = rw_test_lib:run_escript(["bench", "scale", "--counts", "20,60", "--until", "100"]),
    #{<<"until_ms">> := 100, <<"counts">> := [#{<<"spheres">> := 20, <<"vs_first">> := 1.0} = First,
                                               #{<<"spheres">> := 60, <<"vs_first">> := Vs} = Second]} =
        last_json_line(Out),
    %% every count over the same simulated time, small ones several times
    %% over (rw_cli_scale_tests has how many)
    [?assertMatch(#{<<"simulated_ms">> := 100, <<"runs">> := 20}, Count) || Count <- [First, Second]],
    [?assertMatch({match, _}, re:run(Err, "round 1 of 1: " ++ N ++ " spheres, 20 runs of 100 ms")) || N <- ["20", "60"]],
    [begin
         ?assert(Rate > 0 andalso Running > 0 andalso Wall > 0),
         ?assertMatch([_, _, _], Kib)
     end || #{<<"body_substeps_per_s">> := Rate, <<"running_per_s">> := Running, <<"wall_ms">> := Wall,
              <<"kib_per_body">> := Kib} <- [First, Second]],
    ?assertBitwise(maps:get(<<"running_per_s">>, Second) / maps:get(<<"running_per_s">>, First), Vs),
    ?assertMatch({match, _}, re:run(Out, "\\| 60 \\| [0-9]+ \\|")).

%% In rounds: each count once a round (a line on stderr each), its rates
%% the medians of its rounds and its ratio to the first count the median of
%% the rounds' ratios, with their range in the table and the JSON line.
bench_scale_rounds(_Config) ->
    {0, Out, Err} = rw_test_lib:run_escript(["bench", "scale", "--counts", "20,60", "--until", "100", "--rounds", "2"]),
    #{<<"rounds">> := 2, <<"counts">> := [First, Second]} = last_json_line(Out),
    #{<<"running_per_s_rounds">> := [F1, F2], <<"running_per_s">> := FRate, <<"vs_first">> := FVs} = First,
    #{<<"running_per_s_rounds">> := [S1, S2], <<"running_per_s">> := SRate, <<"vs_first">> := SVs,
      <<"vs_first_range">> := Range} = Second,
    ?assertBitwise((F1 + F2) / 2, FRate),
    ?assertBitwise((S1 + S2) / 2, SRate),
    ?assertBitwise(1.0, FVs),
    ?assertBitwise((S1 / F1 + S2 / F2) / 2, SVs),
    ?assertBitwise(lists:sort([S1 / F1, S2 / F2]), Range),
    ?assertMatch({match, _}, re:run(Out, "\\| 60 \\| 20 \\| 100 \\| [0-9]+ \\| [^|]+ \\| [^|]+ \\| [0-9.]+ \\([0-9.]+-[0-9.]+\\) \\|")),
    [?assertMatch({match, _}, re:run(Err, Line))
     || Line <- ["round 1 of 2: 20 spheres", "round 1 of 2: 60 spheres", "round 2 of 2: 60 spheres",
                 "round 2 of 2: 20 spheres"]],
    %% the second round runs the counts the other way round
    {match, [{R2a, _}]} = re:run(Err, "round 2 of 2: 60 spheres"),
    {match, [{R2b, _}]} = re:run(Err, "round 2 of 2: 20 spheres"),
    ?assert(R2a < R2b).

%% The machine's own scaling: one JSON line with every pair's times, whose
%% ratios give the median and the range, and the schedulers put back.
bench_machine(_Config) ->
    {0, Out, _} = rw_test_lib:run_escript(["bench", "machine", "--repeats", "2"]),
    #{<<"one_scheduler_ms">> := [A1, A2], <<"two_schedulers_ms">> := [B1, B2], <<"scaling">> := S,
      <<"scaling_min">> := Min, <<"scaling_max">> := Max} = last_json_line(Out),
    [?assert(T > 0) || T <- [A1, A2, B1, B2]],
    ?assertBitwise(lists:sort([A1 / B1, A2 / B2]), [Min, Max]),
    ?assert(abs(S - (Min + Max) / 2) < 1.0e-9).
