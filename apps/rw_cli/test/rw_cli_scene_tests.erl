%% rw_cli_scene: the names suggested for an unknown scene, and the
%% description's wrapping.
-module(rw_cli_scene_tests).
-include_lib("eunit/include/eunit.hrl").

closest_test_() ->
    Known = ["ball_drop", "bouncing_200_100", "bouncing_200_250", "bouncing_50_250", "projectile"],
    [?_assertEqual(["projectile"], rw_cli_scene:closest("projectle", Known)),
     ?_assertEqual(["bouncing_200_100", "bouncing_200_250", "bouncing_50_250"],
                   rw_cli_scene:closest("bouncing_200", Known)),
     ?_assertEqual(["bouncing_50_250"], rw_cli_scene:closest("50_250", Known)),
     ?_assertEqual([], rw_cli_scene:closest("zzz", Known)),
     ?_assertEqual(["ball_drop"], rw_cli_scene:closest("ball_drop", Known))].

wrap_test_() ->
    Text = "one two three four five six",
    [?_assertEqual(["one two", "three", "four", "five six"], rw_cli_scene:wrap(Text, 8)),
     ?_assertEqual([Text], rw_cli_scene:wrap(Text, 100)),
     ?_assertEqual(["a", "longerthanwidth", "b"], rw_cli_scene:wrap("a longerthanwidth b", 4)),
     ?_assertEqual([], rw_cli_scene:wrap("  \n ", 10)),
     ?_assertEqual(["x y"], rw_cli_scene:wrap("x\n  y", 10))].

%% An unknown name outside an escript looks in ./scenarios only.
resolve_test_() ->
    [?_assertEqual("some/path", rw_cli_scene:resolve("some/path")),
     ?_assertEqual("missing.json", rw_cli_scene:resolve("missing.json")),
     ?_assertThrow({usage, "the scene argument is empty"}, rw_cli_scene:resolve("")),
     ?_assertThrow({bad_input, "no_such_scene_here: no such scene (looked for no_such_scene_here, "
                                "scenarios/no_such_scene_here.json)" ++ _},
                   rw_cli_scene:resolve("no_such_scene_here"))].
