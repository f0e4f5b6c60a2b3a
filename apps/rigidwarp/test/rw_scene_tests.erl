%% Scene validation: every rejection names the JSON path and the problem.
-module(rw_scene_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include("rigidwarp.hrl").

base() ->
    #{<<"name">> => <<"t">>, <<"duration_ms">> => 100,
      <<"bodies">> => [sphere(<<"a">>, [0, 0, 0]), sphere(<<"b">>, [3, 0, 0])]}.

sphere(Id, Pos) ->
    #{<<"id">> => Id, <<"shape">> => <<"sphere">>, <<"radius">> => 0.5, <<"mass">> => 1.0,
      <<"position">> => Pos}.

%% The error message for a scene, "" when it is valid.
error_of(Map) ->
    case rw_scene:from_map(Map, #{file => "s.json"}) of
        {ok, _} -> "";
        {error, E} -> rw_scene:format_error(E)
    end.

set_body(N, Key, Value) ->
    Bodies = maps:get(<<"bodies">>, base()),
    B = lists:nth(N + 1, Bodies),
    (base())#{<<"bodies">> => lists:sublist(Bodies, N) ++ [B#{Key => Value}] ++ lists:nthtail(N + 1, Bodies)}.

valid_scene_test() ->
    {ok, #scene{spheres = [#sphere{id = <<"a">>, idx = 0}, #sphere{id = <<"b">>, idx = 1}],
                substep = 1, stride = 64, frame = 10, tick_us = 1000, model = #model{gravity = undefined,
                                                                              rotation = false}}} =
        rw_scene:from_map(base(), #{}).

messages_name_the_path_test_() ->
    Cases =
        [{set_body(0, <<"radius">>, -1), "s.json: $.bodies[0].radius: must be positive"},
         {set_body(1, <<"mass">>, 0), "$.bodies[1].mass: must be positive"},
         {set_body(1, <<"mass">>, <<"heavy">>), "$.bodies[1].mass: must be a number, got \"heavy\""},
         {set_body(0, <<"position">>, [0, 0]), "$.bodies[0].position: must be an array of 3 numbers"},
         {set_body(0, <<"position">>, [0, 1.0e300, 0]), "$.bodies[0].position[1]: must be at most"},
         {set_body(1, <<"id">>, <<"a">>), "$.bodies[1].id: duplicate id \"a\" (first used at $.bodies[0])"},
         {set_body(1, <<"position">>, [0.5, 0, 0]), "$.bodies[1].position: sphere b overlaps sphere a"},
         {set_body(0, <<"shape">>, <<"cone">>), "$.bodies[0].shape: unknown shape \"cone\""},
         {set_body(0, <<"colour">>, <<"red">>), "$.bodies[0].colour: unknown key"},
         {set_body(0, <<"angular_velocity">>, [1, 0, 0]), "$.bodies[0].angular_velocity: needs \"rotation\": true"},
         {(base())#{<<"model">> => #{<<"restitution">> => 1.5}}, "$.model.restitution: must be between 0 and 1"},
         {(base())#{<<"model">> => #{<<"integrator">> => <<"rk4">>}}, "$.model.integrator: must be"},
         {(base())#{<<"substep_ms">> => 3}, "$.duration_ms: 100 ms is not a multiple of the substep (3 ms)"},
         {(base())#{<<"stride_ms">> => 0}, "$.stride_ms: must be a positive number of milliseconds, got 0"},
         {(base())#{<<"frame_ms">> => 2.5}, "$.frame_ms: 2.5 ms is not a multiple of the substep (1 ms)"},
         {(base())#{<<"frame_ms">> => <<"10">>}, "$.frame_ms: must be a positive number of milliseconds, got \"10\""},
         {maps:remove(<<"name">>, base()), "$.name: is required"},
         {(base())#{<<"bodies">> => []}, "$.bodies: the scene has no dynamic body"},
         {(base())#{<<"bodies">> => [#{<<"id">> => <<"p">>, <<"shape">> => <<"plane">>, <<"normal">> => [0, 0, 0]},
                                     sphere(<<"a">>, [0, 5, 0])]},
          "$.bodies[0].normal: must not be the zero vector"},
         {(base())#{<<"bodies">> => [#{<<"id">> => <<"p">>, <<"shape">> => <<"plane">>, <<"normal">> => [0, 1, 0]},
                                     sphere(<<"a">>, [0, 0.2, 0])]},
          "$.bodies[1].position: sphere a overlaps static p"},
         {(base())#{<<"bodies">> => [#{<<"id">> => <<"c">>, <<"shape">> => <<"cylinder">>, <<"static">> => false,
                                       <<"radius">> => 1, <<"half_length">> => 1, <<"position">> => [0, 9, 0]},
                                     sphere(<<"a">>, [0, 0, 0])]},
          "$.bodies[0].static: a cylinder must be static"},
         %% (20 that cannot fit: placement gives up after 1000 tries a
         %% sphere, within some 60 ms; a count of 1000 would take seconds,
         %% near eunit's timeout on a busy machine)
         {(base())#{<<"generators">> => [#{<<"type">> => <<"random">>, <<"id_prefix">> => <<"r">>,
                                           <<"count">> => 20, <<"min">> => [10, 10, 10], <<"max">> => [12, 12, 12],
                                           <<"radius">> => 0.5, <<"mass">> => 1}]},
          "$.generators[0].count: cannot place 20 spheres"},
         {(base())#{<<"extra">> => 1}, "$.extra: unknown key"}],
    [{Expected, ?_assertMatch({match, _}, re:run(error_of(Map), "\\Q" ++ Expected ++ "\\E"))}
     || {Map, Expected} <- Cases].

bad_json_test_() ->
    [?_assertMatch({error, {scene_error, _, [], "invalid JSON" ++ _}}, rw_scene:from_binary(<<"{\"name\": ">>, #{})),
     ?_assertMatch({error, {scene_error, _, [], "invalid JSON" ++ _}}, rw_scene:from_binary(<<"{\"a\": 1e400}">>, #{})),
     ?_assertMatch({error, {scene_error, _, [], "a scene must be a JSON object"}}, rw_scene:from_binary(<<"[1]">>, #{})),
     ?_assertMatch({error, {scene_error, _, [], "invalid JSON" ++ _}}, rw_scene:from_binary(<<0, 255, 12>>, #{}))].

overrides_apply_before_validation_test() ->
    {ok, #scene{duration = 50, substep = 2, stride = 8, tick_us = 1000}} =
        rw_scene:from_map(base(), #{overrides => #{duration_ms => 50, substep_ms => 2, stride_ms => 8,
                                                  frame_ms => 10}}),
    {error, E} = rw_scene:from_map(base(), #{overrides => #{duration_ms => 51, substep_ms => 2}}),
    ?assertMatch({match, _}, re:run(rw_scene:format_error(E), "duration_ms: 51 ms")).

%% A substep below 1 ms makes the tick finer: the largest whole number of
%% microseconds dividing 1 ms and the substep. Whole ms keep the 1 ms tick.
sub_millisecond_substeps_test_() ->
    Load = fun(Times) -> rw_scene:from_map(maps:merge(base(), Times), #{}) end,
    Dt = fun({ok, #scene{model = #model{dt = D}}}) -> D end,
    Half = Load(#{<<"substep_ms">> => 0.5, <<"stride_ms">> => 64, <<"frame_ms">> => 10, <<"duration_ms">> => 100}),
    Micro = Load(#{<<"substep_ms">> => 0.001, <<"duration_ms">> => 20}),
    Two = Load(#{<<"substep_ms">> => 2}),
    [?_assertMatch({ok, #scene{tick_us = 500, substep = 1, stride = 128, frame = 20, duration = 200}}, Half),
     ?_test(?assertBitwise(0.0005, Dt(Half))),
     ?_assertMatch({ok, #scene{tick_us = 1, substep = 1, duration = 20000}}, Micro),
     ?_test(?assertBitwise(1.0e-6, Dt(Micro))),
     %% 1.5 ms: ticks of 0.5 ms, 3 per substep
     ?_assertMatch({ok, #scene{tick_us = 500, substep = 3, frame = 30}},
                   Load(#{<<"substep_ms">> => 1.5, <<"frame_ms">> => 15, <<"stride_ms">> => 15,
                          <<"duration_ms">> => 30})),
     ?_assertMatch({ok, #scene{tick_us = 1000, substep = 2}}, Load(#{<<"substep_ms">> => 2.0})),
     %% the same substep from an override
     ?_assertMatch({ok, #scene{tick_us = 250, substep = 1}},
                   rw_scene:from_map(base(), #{overrides => #{substep_ms => 0.25}})),
     ?_test(?assertBitwise(0.002, Dt(Two))),
     ?_assertEqual("$.substep_ms: must be a whole number of microseconds (0.001 ms at the finest), got 0.0005 ms",
                   rw_scene:format_error(element(2, Load(#{<<"substep_ms">> => 0.0005})))),
     ?_assertEqual("$.frame_ms: 10 ms is not a multiple of the substep (0.3 ms)",
                   rw_scene:format_error(element(2, Load(#{<<"substep_ms">> => 0.3, <<"duration_ms">> => 30,
                                                           <<"frame_ms">> => 10})))),
     ?_assertEqual("$.substep_ms: must be a positive number of milliseconds, got -1",
                   rw_scene:format_error(element(2, Load(#{<<"substep_ms">> => -1}))))].

ms_of_ticks_test_() ->
    {ok, Half} = rw_scene:from_map((base())#{<<"substep_ms">> => 0.5}, #{}),
    {ok, Whole} = rw_scene:from_map(base(), #{}),
    [?_assertEqual(3, rw_scene:ms(Whole, 3)),
     ?_assertEqual(-1, rw_scene:ms(Half, -1)),
     ?_test(?assertBitwise(0.5, rw_scene:ms(Half, 1))),
     ?_assertEqual(10, rw_scene:ms(Half, 20)),
     ?_assertEqual(20, rw_scene:whole_ms(20.0)),
     ?_test(?assertBitwise(0.5, rw_scene:whole_ms(0.5)))].

model_overrides_test() ->
    Map = (base())#{<<"model">> => #{<<"integrator">> => <<"explicit_euler">>, <<"ccd">> => true}},
    {ok, #scene{model = #model{integrator = explicit_euler, ccd = true}}} = rw_scene:from_map(Map, #{}),
    {ok, #scene{model = #model{integrator = verlet, ccd = false}}} =
        rw_scene:from_map(Map, #{overrides => #{integrator => verlet, ccd => false}}).

generators_are_deterministic_test() ->
    Map = (base())#{<<"generators">> =>
                        [#{<<"type">> => <<"random">>, <<"id_prefix">> => <<"r">>, <<"count">> => 20, <<"seed">> => 5,
                           <<"min">> => [10, 10, 10], <<"max">> => [15, 15, 15], <<"radius">> => 0.3,
                           <<"mass">> => 1, <<"speed">> => 2},
                         #{<<"type">> => <<"grid">>, <<"id_prefix">> => <<"g">>, <<"count">> => [3, 1, 2],
                           <<"origin">> => [-10, 0, 0], <<"spacing">> => [1, 1, 1], <<"radius">> => 0.25,
                           <<"mass">> => 2}]},
    {ok, S1} = rw_scene:from_map(Map, #{}),
    {ok, S2} = rw_scene:from_map(Map, #{}),
    ?assertBitwise(S1#scene.initial, S2#scene.initial),
    Ids = [Id || #sphere{id = Id} <- S1#scene.spheres],
    ?assertEqual(2 + 20 + 6, length(Ids)),
    ?assert(lists:member(<<"r07">>, Ids)),
    ?assert(lists:member(<<"g5">>, Ids)),
    %% ranked by id: idx follows the sorted ids
    ?assertEqual(lists:sort(Ids), Ids),
    [?assert(rw_vec:len(V) < 2.0) || #st{v = V} <- S1#scene.initial].

rotation_adds_angular_state_test() ->
    {ok, #scene{initial = [#st{q = Q, w = W} | _]}} =
        rw_scene:from_map((base())#{<<"model">> => #{<<"rotation">> => true}}, #{}),
    ?assertBitwise({{{0.0, 0.0, 0.0}, 1.0}, {0.0, 0.0, 0.0}}, {Q, W}).

zero_gravity_is_no_gravity_test() ->
    {ok, #scene{model = #model{gravity = undefined, rest_speed = Zero}}} =
        rw_scene:from_map((base())#{<<"model">> => #{<<"gravity">> => [0, 0, 0]}}, #{}),
    ?assertBitwise(0.0, Zero),
    {ok, #scene{model = #model{gravity = G, rest_speed = RS}}} =
        rw_scene:from_map((base())#{<<"model">> => #{<<"gravity">> => [0, -10, 0]}}, #{}),
    ?assertBitwise({0.0, -10.0, 0.0}, G),
    ?assert(abs(RS - 0.02) < 1.0e-12).

%%% Limits (rw_scene_limits): what would overflow or list cells without end

limits_test_() ->
    Gen = fun(R, M) -> (base())#{<<"generators">> => [#{<<"type">> => <<"grid">>, <<"id_prefix">> => <<"g">>,
                                                         <<"count">> => [1, 1, 1], <<"origin">> => [0, 5, 0],
                                                         <<"spacing">> => [1, 1, 1], <<"radius">> => R,
                                                         <<"mass">> => M}]} end,
    Axis = fun(A) -> (base())#{<<"bodies">> => [#{<<"id">> => <<"c">>, <<"shape">> => <<"cylinder">>, <<"radius">> => 1,
                                                   <<"half_length">> => 1, <<"axis">> => A, <<"position">> => [0, 9, 0]},
                                                 sphere(<<"a">>, [0, 0, 0])]} end,
    Fast = fun(V, Model) -> (set_body(0, <<"velocity">>, [V, 0, 0]))#{<<"model">> => Model} end,
    Cases = [{set_body(0, <<"radius">>, 1.0e-10), "$.bodies[0].radius: must be from 1.0e-9 to 1.0e12 m"},
             {set_body(0, <<"mass">>, 1.0e-21), "$.bodies[0].mass: must be from 1.0e-20 to 1.0e12 kg"},
             {Gen(1.0e-10, 1), "$.generators[0].radius: must be from 1.0e-9"},
             {Gen(0.5, 1.0e-300), "$.generators[0].mass: must be from 1.0e-20"},
             {Axis([1.0e-200, 0, 0]), "$.bodies[0].axis: is degenerate: its length 1.0e-200 is below 1.0e-150"},
             {(base())#{<<"cell_size">> => 0.5 / 8.5}, "$.cell_size: must be at least 1/8 of the largest radius (0.0625 m here)"},
             %% a's energy may all go to b (equal masses: the same bound);
             %% 1e6 m/s with CCD sweeps past the caps, 1e4 m/s does not
             {Fast(1.0e6, #{<<"ccd">> => true}), "$.bodies[1]: with CCD, sphere b could reach 1.1e6 m/s"},
             {Fast(1.0e6, #{<<"ccd">> => true, <<"gravity">> => [0, -9.81, 0]}),
              "(all of the scene's kinetic energy in it, and what gravity adds over 0.1 s)"}],
    [{Expected, ?_assertMatch({match, _}, re:run(error_of(Map), "\\Q" ++ Expected ++ "\\E"))}
     || {Map, Expected} <- Cases]
        ++ [?_assertEqual("", error_of(Map)) || Map <- [(base())#{<<"cell_size">> => 0.5 / 8}, Gen(1.0e-9, 1.0e-20),
                                                        Axis([1.0e-150, 0, 0]), Fast(1.0e6, #{}),
                                                        Fast(1.0e4, #{<<"ccd">> => true})]].

%% A key given twice is refused where it is given the second time, at any
%% depth; without one, the scene is the one a map decoding gives, for
%% every bundled scene.
duplicate_keys_test_() ->
    Dup = fun(Json) ->
                  {error, E} = rw_scene:from_binary(Json, #{}),
                  rw_scene:format_error(E)
          end,
    Same = fun(File) ->
                   {ok, Bin} = file:read_file(File),
                   {ok, FromText} = rw_scene:from_binary(Bin, #{}),
                   {ok, FromMap} = rw_scene:from_map(jiffy:decode(Bin, [return_maps]), #{}),
                   ?assertBitwise(FromMap, FromText)
           end,
    Scenes = filelib:wildcard(filename:join([rw_test_lib:root(), "scenarios", "*.json"])),
    [?_assertEqual("$.model.ccd: duplicate key (a key may appear once in an object)",
                   Dup(<<"{\"name\":\"t\",\"model\":{\"ccd\":true,\"ccd\":false},\"duration_ms\":1}">>)),
     ?_assertEqual("$.generators[1].radius: duplicate key (a key may appear once in an object)",
                   Dup(<<"{\"generators\":[{},{\"radius\":1,\"mass\":1,\"radius\":2}]}">>)),
     ?_assertEqual("$.name: duplicate key (a key may appear once in an object)",
                   Dup(<<"{\"name\":\"t\",\"name\":\"t\"}">>)),
     ?_assert(length(Scenes) >= 20)
     | [?_test(Same(F)) || F <- Scenes]].

%% The speed bound holds where a heavy ball hands its fall to a light one
%% above it: dropped together 1 m onto a floor (restitution 1), the heavy
%% one bounces back into the light one, which leaves at some 3 x 4.4 m/s
%% at 0.45 s, far above what gravity alone gives by then (g t); the bound
%% counts every fall's energy as the light one's.
speed_bound_holds_when_a_fall_moves_to_a_lighter_sphere_test() ->
    Floor = #{<<"id">> => <<"floor">>, <<"shape">> => <<"plane">>, <<"normal">> => [0, 1, 0], <<"offset">> => 0},
    Light = (sphere(<<"light">>, [0, 2.1001, 0]))#{<<"radius">> => 0.1},
    Heavy = (sphere(<<"heavy">>, [0, 1.5, 0]))#{<<"mass">> => 100.0},
    {ok, #scene{spheres = Spheres, initial = Initial, model = Model} = Scene} =
        rw_scene:from_map(#{<<"name">> => <<"t">>, <<"duration_ms">> => 500, <<"frame_ms">> => 1,
                            <<"model">> => #{<<"gravity">> => [0, -9.81, 0], <<"restitution">> => 1.0},
                            <<"bodies">> => [Floor, Light, Heavy]}, #{}),
    [HeavyBound, LightBound] = rw_scene_limits:speed_bounds([{S, St, []} || {S, St} <- lists:zip(Spheres, Initial)],
                                                            Model, 0.5),
    Self = self(),
    {ok, _} = rw_reference:run(Scene, #{on_frame => fun(F) -> Self ! {frame, F} end}),
    Fastest = lists:max(fastest_light(Self)),
    ?assert(Fastest > 2.0 * 9.81 * 0.5),
    ?assert(Fastest =< LightBound),
    ?assert(HeavyBound < LightBound).

fastest_light(_Self) ->
    receive {frame, {frame, _, Bodies}} ->
            {_, _, V, _, _} = lists:keyfind(<<"light">>, 1, Bodies),
            [rw_vec:len(V) | fastest_light(_Self)]
    after 0 -> []
    end.
