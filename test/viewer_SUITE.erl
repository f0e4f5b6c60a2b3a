%% The viewer's JSON API (rw_viewer, rw_viewer_http) over HTTP, as the page
%% reads it: a live simulation while it runs and after it is stopped, and
%% a frames file played back. The page itself is checked in a browser by
%% `make viewer-test` (test/viewer).
-module(viewer_SUITE).
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([live_api/1, playback_api/1, bad_requests/1]).

suite() -> [{timetrap, {minutes, 2}}].

all() -> [live_api, playback_api, bad_requests].

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    {ok, _} = application:ensure_all_started(inets),
    Config.

end_per_suite(_Config) -> ok.

%% Status and frames while a run goes on, the same frames as the engine's
%% ring, and after stop/1 an error status and no frames.
live_api(_Config) ->
    {ok, Sim} = rigidwarp:start(rw_test_lib:scenario("head_on_elastic.json"), #{}),
    {ok, Url} = rigidwarp:view(Sim, #{port => 0}),
    ok = rigidwarp:await(Sim, 10000),
    {200, Scene} = get_json(Url, "api/scene"),
    ?assertMatch(#{<<"name">> := <<"head_on_elastic">>, <<"source">> := <<"live">>, <<"frame_ms">> := _,
                   <<"end_ms">> := 1000, <<"spheres">> := [_, _], <<"fixtures">> := _}, Scene),
    {200, Status} = get_json(Url, "api/status"),
    ?assertMatch(#{<<"gvt">> := 1000}, Status),
    {200, Frames} = get_json(Url, "api/frames?after=-1"),
    Ring = rigidwarp:frames_after(Sim, -1, 200),
    ?assertEqual(length(Ring), length(Frames)),
    ?assertEqual([T || {frame, T, _} <- Ring], [T || #{<<"t">> := T} <- Frames]),
    {200, []} = get_json(Url, "api/frames?after=1000"),
    ok = rigidwarp:stop(Sim),
    ?assertEqual({200, #{<<"error">> => <<"the simulation has been stopped">>}}, get_json(Url, "api/status")),
    ?assertEqual({200, []}, get_json(Url, "api/frames?after=-1")).

%% A frames file's frames after a time, and the status of the playback.
playback_api(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Scene} = rigidwarp:load(File, #{}),
    Self = self(),
    {ok, _} = rigidwarp:run_scene(Scene, #{engine => reference, on_frame => fun(F) -> Self ! {frame, F} end}),
    Frames = drain(),
    {ok, Server} = rw_viewer:start({playback, Scene, Frames}, #{port => 0}),
    Url = rw_viewer:url(Server),
    try
        {200, #{<<"source">> := <<"playback">>, <<"end_ms">> := 1000}} = get_json(Url, "api/scene"),
        ?assertEqual({200, #{<<"gvt">> => 1000, <<"end_ms">> => 1000, <<"frames">> => length(Frames)}},
                     get_json(Url, "api/status")),
        {200, After} = get_json(Url, "api/frames?after=500"),
        ?assertEqual([T || {frame, T, _} <- Frames, T > 500], [T || #{<<"t">> := T} <- After])
    after
        rw_viewer:stop(Server)
    end.

bad_requests(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Scene} = rigidwarp:load(File, #{}),
    {ok, Server} = rw_viewer:start({playback, Scene, []}, #{port => 0}),
    Url = rw_viewer:url(Server),
    try
        ?assertEqual({400, #{<<"error">> => <<"after must be a number (ms)">>}}, get_json(Url, "api/frames?after=x")),
        ?assertEqual({404, #{<<"error">> => <<"unknown API path">>}}, get_json(Url, "api/nothing"))
    after
        rw_viewer:stop(Server)
    end.

drain() ->
    receive {frame, F} -> [F | drain()] after 0 -> [] end.

get_json(Url, Path) ->
    {ok, {{_, Code, _}, _Headers, Body}} = httpc:request(get, {Url ++ Path, []}, [], [{body_format, binary}]),
    {Code, jiffy:decode(Body, [return_maps])}.
