%% inets httpd module answering the viewer's /api/ requests (see rw_viewer);
%% every other request goes on to mod_alias and mod_get (the static page).
-module(rw_viewer_http).
-include_lib("inets/include/httpd.hrl").
-export([do/1]).

-spec do(#mod{}) -> {proceed, list()}.
do(#mod{method = "GET", request_uri = Uri, config_db = Db, data = Data} = Mod) ->
    {Path, Query} = case string:split(Uri, "?") of
                        [P, Q] -> {P, uri_string:dissect_query(Q)};
                        [P] -> {P, []}
                    end,
    case Path of
        "/api/" ++ What ->
            Port = httpd_util:lookup(Db, port),
            Reply = case persistent_term:get({rw_viewer, Port}, undefined) of
                        undefined -> {503, #{error => <<"no source">>}};
                        Source -> answer(What, Query, Source)
                    end,
            Body = body(Reply),
            Headers = [{content_length, integer_to_list(byte_size(Body))} | headers(Reply)],
            {proceed, [{response, {response, Headers, [Body]}} | Data]};
        _ ->
            _ = Mod,
            {proceed, Data}
    end;
do(#mod{data = Data}) ->
    {proceed, Data}.

answer("scene", _Query, Source) ->
    {200, rw_viewer:scene_json(Source)};
answer("status", _Query, Source) ->
    {200, rw_viewer:status(Source)};
answer("frames", Query, Source) ->
    case number_param("after", Query, -1) of
        {ok, After} ->
            Frames = rw_viewer:frames_after(Source, After, 200),
            {200, {raw, [$[, lists:join($,, [string:trim(rw_frames:encode(F), trailing) || F <- Frames]), $]]}};
        error ->
            {400, #{error => <<"after must be a number (ms)">>}}
    end;
answer(_, _, _) ->
    {404, #{error => <<"unknown API path">>}}.

%% Frame times are in ms, fractional with a sub-millisecond frame interval.
number_param(Name, Query, Default) ->
    case lists:keyfind(Name, 1, Query) of
        false -> {ok, Default};
        {_, V} ->
            Bin = unicode:characters_to_binary(V),
            try {ok, binary_to_integer(Bin)}
            catch error:badarg ->
                    try {ok, binary_to_float(Bin)}
                    catch error:badarg -> error
                    end
            end
    end.

headers({Code, _}) ->
    [{code, Code}, {content_type, "application/json"}, {cache_control, "no-store"}].

body({_, {raw, IoData}}) -> iolist_to_binary(IoData);
body({_, Map}) -> iolist_to_binary(jiffy:encode(Map)).
