%% The browser viewer's server: OTP's inets httpd serving the page under
%% priv/viewer (three.js comes from npm into priv/viewer/node_modules) and a
%% small JSON API read by the page:
%%   GET /api/scene              bodies (id, radius), fixtures, frame interval
%%   GET /api/frames?after=T     committed frames after T ms (at most 200)
%%   GET /api/status             GVT, end time, realtime factor, counters
%% Two sources: a running simulation's ETS frame ring (live) or the frames
%% of a file written by `rigidwarp run --frames` (playback). Bound to
%% 127.0.0.1 unless told otherwise.
-module(rw_viewer).
-include("rigidwarp.hrl").
-export([start/2, stop/1, url/1, viewer_dir/0, prepare/0]).
-export([scene_json/1, frames_after/3, status/1]).
-export_type([source/0, server/0]).

-type source() :: {live, rw_timewarp:handle()} | {playback, #scene{}, [rw_reference:frame()]}.
%% As the server keeps it: a live source with its scene, read once.
-type kept() :: {live, rw_timewarp:handle(), #scene{}} | {playback, #scene{}, [rw_reference:frame()]}.
-opaque server() :: #{pid := pid(), port := inet:port_number(), host := string()}.
-type options() :: #{port => inet:port_number(), bind => inet:ip4_address()}.

-define(MAX_FRAMES_PER_CALL, 200).

%% Start inets and load the web server's code now: once a simulation keeps
%% every scheduler busy, loading dozens of modules takes seconds.
-spec prepare() -> ok.
prepare() ->
    {ok, _} = application:ensure_all_started(inets),
    {ok, Mods} = application:get_key(inets, modules),
    Web = [M || M <- Mods, lists:any(fun(P) -> lists:prefix(P, atom_to_list(M)) end, ["httpd", "mod_", "http_"])],
    _ = code:ensure_modules_loaded([rw_viewer_http, rw_frames | Web]),
    ok.

%% Start a server for Source on the port Opts give, else on the
%% application's viewer_port; port 0 picks a free port.
-spec start(source(), options()) -> {ok, server()} | {error, string()}.
start(Source, Opts) ->
    Dir = viewer_dir(),
    Asked = maps:get(port, Opts, application:get_env(rigidwarp, viewer_port, 8765)),
    case filelib:is_regular(filename:join(Dir, "index.html")) of
        false ->
            {error, "viewer files not found in " ++ Dir};
        true ->
            ok = prepare(),
            Bind = maps:get(bind, Opts, {127, 0, 0, 1}),
            Config = [{port, Asked},
                      {server_name, "rigidwarp"},
                      {server_root, Dir},
                      {document_root, Dir},
                      {bind_address, Bind},
                      {directory_index, ["index.html"]},
                      {modules, [rw_viewer_http, mod_alias, mod_get, mod_head]},
                      %% ES modules are refused unless served as JavaScript
                      {mime_types, [{"html", "text/html; charset=utf-8"}, {"js", "text/javascript"},
                                    {"mjs", "text/javascript"}, {"css", "text/css"},
                                    {"json", "application/json"}, {"png", "image/png"},
                                    {"svg", "image/svg+xml"}]}],
            case inets:start(httpd, Config) of
                {ok, Pid} ->
                    [{port, Port}] = httpd:info(Pid, [port]),
                    persistent_term:put({?MODULE, Port}, keep(Source)),
                    {ok, #{pid => Pid, port => Port, host => inet:ntoa(Bind)}};
                {error, Reason} ->
                    {error, lists:flatten(io_lib:format("cannot start the viewer on port ~p: ~p",
                                                        [Asked, Reason]))}
            end
    end.

-spec stop(server()) -> ok.
stop(#{pid := Pid, port := Port}) ->
    _ = persistent_term:erase({?MODULE, Port}),
    _ = inets:stop(httpd, Pid),
    ok.

-spec url(server()) -> string().
url(#{host := Host, port := Port}) -> lists:flatten(io_lib:format("http://~s:~b/", [Host, Port])).

%% priv/viewer of the rigidwarp application (rw_priv: the escript's too).
-spec viewer_dir() -> file:filename().
viewer_dir() -> filename:join(rw_priv:dir(), "viewer").

keep({live, Sim}) -> {live, Sim, rw_timewarp:scene(Sim)};
keep(Playback) -> Playback.

%%% What the API answers (used by rw_viewer_http)

-spec scene_json(kept()) -> map().
scene_json(Source) ->
    #scene{name = Name, spheres = Spheres, fixtures = Fixtures, frame = F} = Scene = scene(Source),
    #{name => Name, frame_ms => rw_scene:ms(Scene, F),
      end_ms => case Source of
                    {playback, _, [_ | _] = Frames} -> element(2, lists:last(Frames));
                    _ -> rw_scene:duration_ms(Scene)
                end,
      source => case Source of {live, _, _} -> live; _ -> playback end,
      spheres => [#{id => Id, radius => R} || #sphere{id = Id, radius = R} <- Spheres],
      fixtures => [fixture(Fx) || Fx <- Fixtures]}.

fixture(#fixture{id = Id, shape = {plane, N, D}}) -> #{id => Id, shape => plane, normal => vec(N), offset => D};
fixture(#fixture{id = Id, shape = {cylinder, C, A, R, H}}) ->
    #{id => Id, shape => cylinder, position => vec(C), axis => vec(A), radius => R, half_length => H};
fixture(#fixture{id = Id, shape = {box, C, H, Kind}}) ->
    #{id => Id, shape => box, position => vec(C), half_extents => vec(H), hollow => Kind =:= hollow}.

vec({X, Y, Z}) -> [X, Y, Z].

scene({live, _, S}) -> S;
scene({playback, S, _}) -> S.

%% Frames after T (ms), oldest first, as the frames file encodes them.
-spec frames_after(kept(), number(), pos_integer()) -> [rw_reference:frame()].
frames_after({playback, _, Frames}, T, Max) ->
    lists:sublist([Fr || {frame, FT, _} = Fr <- Frames, FT > T], min(Max, ?MAX_FRAMES_PER_CALL));
frames_after({live, {rw_sim, _, Ring}, _}, T, Max) ->
    case alive(fun() -> rw_ring:frames_after(Ring, T, min(Max, ?MAX_FRAMES_PER_CALL)) end) of
        stopped -> [];
        Frames -> Frames
    end.

-spec status(kept()) -> map().
status({playback, Scene, Frames}) ->
    Last = case Frames of [] -> -1; _ -> element(2, lists:last(Frames)) end,
    #{gvt => Last, end_ms => min(rw_scene:duration_ms(Scene), max(Last, 0)), frames => length(Frames)};
status({live, Sim, _}) ->
    case alive(fun() -> rw_timewarp:stats(Sim) end) of
        stopped -> #{error => <<"the simulation has been stopped">>};
        Stats -> Stats
    end.

%% A stopped simulation's processes and tables are gone: the page keeps
%% polling and is told so.
alive(Fun) ->
    try Fun()
    catch
        exit:{noproc, _} -> stopped;
        error:badarg -> stopped
    end.
