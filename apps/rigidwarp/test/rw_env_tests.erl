%% The application's environment holds the defaults a site may change:
%% viewer_port, the viewer's port when a call names none, ring_frames,
%% the most frames a started run keeps, and native, whether a run uses the
%% engine's C loops unless its options say. rigidwarp.app and
%% config/sys.config give the same values.
-module(rw_env_tests).
-include_lib("eunit/include/eunit.hrl").

top() -> filename:join(code:lib_dir(rigidwarp), "../../../..").

scene() -> filename:join(top(), "scenarios/head_on_elastic.json").

app_file_and_sys_config_agree_test() ->
    {ok, [{application, rigidwarp, Props}]} = file:consult(code:where_is_file("rigidwarp.app")),
    Env = proplists:get_value(env, Props),
    ?assertEqual(8765, proplists:get_value(viewer_port, Env)),
    ?assertEqual(1024, proplists:get_value(ring_frames, Env)),
    {ok, [Sys]} = file:consult(filename:join(top(), "config/sys.config")),
    ?assertEqual(lists:sort(Env), lists:sort(proplists:get_value(rigidwarp, Sys))).

ring_frames_bounds_the_ring_test() ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    with_env(ring_frames, 20,
             fun() ->
                     {ok, Sim} = rigidwarp:start(scene(), #{until => 500}),
                     ok = rigidwarp:await(Sim, 30000),
                     Frames = rigidwarp:frames_after(Sim, -1, 100),
                     ok = rigidwarp:stop(Sim),
                     ?assertEqual(lists:seq(310, 500, 10), [T || {frame, T, _} <- Frames])
             end).

native_is_the_runs_default_test() ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    true = rw_native:loaded(),
    Native = fun(Opts) -> {ok, #{native := N}} = rigidwarp:run(scene(), Opts#{until => 100}), N end,
    ?assert(Native(#{})),
    with_env(native, false, fun() ->
                                    ?assertNot(Native(#{})),
                                    ?assert(Native(#{native => true}))
                            end),
    ?assertNot(Native(#{native => false})),
    %% (a value that is not a boolean: the C loops, and a warning)
    with_env(native, maybe, fun() -> ?assert(Native(#{})) end).

viewer_port_is_the_default_port_test() ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    {ok, Scene} = rigidwarp:load(scene(), #{}),
    with_env(viewer_port, 0,
             fun() ->
                     {ok, Server} = rw_viewer:start({playback, Scene, []}, #{}),
                     Url = rw_viewer:url(Server),
                     ok = rw_viewer:stop(Server),
                     {match, [Port]} = re:run(Url, ":([0-9]+)/$", [{capture, all_but_first, list}]),
                     ?assertNotEqual("8765", Port)
             end).

with_env(Key, Value, Fun) ->
    Old = application:get_env(rigidwarp, Key),
    ok = application:set_env(rigidwarp, Key, Value),
    try Fun()
    after
        case Old of
            {ok, V} -> application:set_env(rigidwarp, Key, V);
            undefined -> application:unset_env(rigidwarp, Key)
        end
    end.
