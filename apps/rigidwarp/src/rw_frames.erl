%% Frames as JSON Lines: one object per committed frame,
%% {"t": MS, "bodies": [{"id", "p", "v"[, "q", "w"]}, ...]}, dynamic bodies
%% sorted by id, doubles in shortest round-trip form.
-module(rw_frames).
-export([encode/1, decode/1, writer/1]).

-spec encode(rw_reference:frame()) -> iodata().
encode({frame, T, Bodies}) ->
    [jiffy:encode(#{<<"t">> => T, <<"bodies">> => [body(B) || B <- Bodies]}), $\n].

body({Id, P, V, undefined, undefined}) ->
    {[{<<"id">>, Id}, {<<"p">>, vec(P)}, {<<"v">>, vec(V)}]};
body({Id, P, V, {QV, QW}, W}) ->
    {[{<<"id">>, Id}, {<<"p">>, vec(P)}, {<<"v">>, vec(V)},
      {<<"q">>, vec(QV) ++ [QW]}, {<<"w">>, vec(W)}]}.

vec({X, Y, Z}) -> [X, Y, Z].

%% Back from one line (for tests and playback).
-spec decode(iodata()) -> rw_reference:frame().
decode(Line) ->
    #{<<"t">> := T, <<"bodies">> := Bodies} = jiffy:decode(Line, [return_maps]),
    {frame, T, [{Id, list_to_tuple(P), list_to_tuple(V), quat(B), wvec(B)}
                || #{<<"id">> := Id, <<"p">> := P, <<"v">> := V} = B <- Bodies]}.

quat(#{<<"q">> := [X, Y, Z, W]}) -> {{X, Y, Z}, W};
quat(_) -> undefined.

wvec(#{<<"w">> := W}) -> list_to_tuple(W);
wvec(_) -> undefined.

%% A frame sink writing to File; the file is first written under a
%% temporary name and renamed by the returned close function, so a failed
%% run never leaves a half-written frames file behind.
-spec writer(file:filename()) -> {ok, fun((rw_reference:frame()) -> ok), fun((ok | abort) -> ok)} |
          {error, term()}.
writer(File) ->
    Tmp = unicode:characters_to_list(File) ++ ".part",
    case file:open(Tmp, [write, raw, binary, delayed_write]) of
        {ok, Fd} ->
            Sink = fun(Frame) -> ok = file:write(Fd, encode(Frame)) end,
            Close = fun(ok) ->
                            ok = file:close(Fd),
                            ok = file:rename(Tmp, File);
                       (abort) ->
                            _ = file:close(Fd),
                            _ = file:delete(Tmp),
                            ok
                    end,
            {ok, Sink, Close};
        {error, _} = Error ->
            Error
    end.
