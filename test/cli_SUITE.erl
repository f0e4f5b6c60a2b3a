%% The rigidwarp escript as a user runs it: exit codes, stderr messages,
%% the summary as the last stdout line, frames files.
-module(cli_SUITE).
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-export([all/0, suite/0]).
-export([help/1, validate_every_scenario/1, summary_is_last_line/1, frames_file/1,
         bad_flags_exit_2/1, bad_scene_exit_2/1, scenes_lists_bundled/1]).

suite() -> [{timetrap, {minutes, 5}}].

all() -> [help, validate_every_scenario, summary_is_last_line, frames_file, bad_flags_exit_2,
          bad_scene_exit_2, scenes_lists_bundled].

help(_Config) ->
    {0, Out, _} = rw_test_lib:run_escript(["help"]),
    ?assertMatch({match, _}, re:run(Out, "usage: rigidwarp")),
    {0, Out2, _} = rw_test_lib:run_escript(["run", "--help"]),
    ?assertMatch({match, _}, re:run(Out2, "--engine")),
    {2, _, Err} = rw_test_lib:run_escript([]),
    ?assertMatch({match, _}, re:run(Err, "usage")).

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

frames_file(Config) ->
    Out = filename:join(?config(priv_dir, Config), "f.jsonl"),
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    {0, _, _} = rw_test_lib:run_escript(["run", Scene, "--until", "100", "--frame-ms", "20", "--quiet",
                                         "--frames", Out]),
    {ok, Bin} = file:read_file(Out),
    Lines = binary:split(string:trim(Bin), <<"\n">>, [global]),
    ?assertEqual([0, 20, 40, 60, 80, 100], [maps:get(<<"t">>, jiffy:decode(L, [return_maps])) || L <- Lines]),
    #{<<"bodies">> := [#{<<"id">> := <<"a">>, <<"p">> := [_, _, _], <<"v">> := [3.0, 0.0, 0.0]},
                       #{<<"id">> := <<"b">>}]} = jiffy:decode(hd(Lines), [return_maps]),
    ?assertNot(filelib:is_file(Out ++ ".part")).

bad_flags_exit_2(_Config) ->
    Scene = rw_test_lib:scenario("head_on_elastic.json"),
    Cases = [{["run", Scene, "--bogus"], "unknown flag --bogus"},
             {["run", Scene, "--until", "abc"], "--until must be a positive integer"},
             {["run", Scene, "--stride", "-5"], "--stride must be a positive integer"},
             {["run", Scene, "--engine", "warp"], "--engine must be timewarp or reference"},
             {["run", Scene, "--schedulers", "999"], "--schedulers must be at most"},
             {["run", Scene, "--until"], "--until needs a value"},
             {["run"], "run needs a scene file"},
             {["frobnicate"], "unknown command frobnicate"},
             {["run", Scene, "--substep", "3"], "not a multiple of the substep"}],
    [begin
         {Code, Out, Err} = rw_test_lib:run_escript(Args),
         ct:log("~p -> ~b~n~s", [Args, Code, Err]),
         ?assertEqual(2, Code),
         ?assertEqual(<<>>, Out),
         ?assertMatch({match, _}, re:run(Err, "\\Q" ++ Expect ++ "\\E"))
     end || {Args, Expect} <- Cases],
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

scenes_lists_bundled(_Config) ->
    {0, Out, _} = rw_test_lib:run_escript(["scenes"]),
    ?assertMatch({match, _}, re:run(Out, "head_on_elastic.json +2 bodies")).
