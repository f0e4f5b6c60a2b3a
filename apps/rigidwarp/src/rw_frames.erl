%% @doc Frames as JSON Lines: one JSON object per committed frame, one line
%% each, in time order.
%% <ul>
%% <li>`t': the frame's time in ms, an integer whenever it is whole;</li>
%% <li>`bodies': every dynamic body, sorted by `id', with `p' its position
%%     [x, y, z] in m and `v' its velocity in m/s after the frame's
%%     contacts; with rotation also `q', its orientation as a unit
%%     quaternion [x, y, z, w], and `w', its angular velocity in rad/s.</li>
%% </ul>
%% Doubles are written in shortest round-trip form (float_to_binary/2's
%% short, which also keeps -0.0 and subnormals: jiffy writes -0.0 as 0.0
%% and 5.0e-324 as 5e-324, which reads back as 0.0), so that a file read
%% back holds the engine's values bit for bit and two runs' files compare
%% byte for byte.
%%
%% ```
%% {"t":0,"bodies":[{"id":"a","p":[-2.0,0.0,0.0],"v":[3.0,0.0,0.0]},{"id":"b","p":[2.0,0.0,0.0],"v":[-3.0,0.0,0.0]}]}
%% {"t":10,"bodies":[{"id":"a","p":[-1.970000000000001,0.0,0.0],"v":[3.0,0.0,0.0]},{"id":"b",...}]}
%% '''
-module(rw_frames).
-export([encode/1, decode/1]).

%% @doc One frame as one line of JSON, newline included.
-spec encode(rw_reference:frame()) -> iodata().
encode({frame, T, Bodies}) ->
    [<<"{\"t\":">>, num(T), <<",\"bodies\":[">>, bodies(Bodies), <<"]}\n">>].

%% Written out rather than built as a term for jiffy: the batch runner
%% encodes every frame while the engine runs on the same cores, and
%% writing the text directly builds no term to walk again.
bodies([]) -> [];
bodies([B]) -> [body(B)];
bodies([B | Rest]) -> [body(B), $, | bodies(Rest)].

body({Id, P, V, Q, W}) ->
    [<<"{\"id\":">>, jiffy:encode(Id), <<",\"p\":">>, vec(P), <<",\"v\":">>, vec(V), rotation(Q, W), $}].

%% q and w only where rotation is modelled.
rotation(undefined, undefined) -> [];
rotation({{X, Y, Z}, QW}, W) ->
    [<<",\"q\":[">>, num(X), $,, num(Y), $,, num(Z), $,, num(QW), <<"],\"w\":">>, vec(W)].

vec({X, Y, Z}) -> [$[, num(X), $,, num(Y), $,, num(Z), $]].

num(F) when is_float(F) -> float_to_binary(F, [short]);
num(I) when is_integer(I) -> integer_to_binary(I).

%% @doc A frame back from one line (for tests and playback).
-spec decode(iodata()) -> rw_reference:frame().
decode(Line) ->
    #{<<"t">> := T, <<"bodies">> := Bodies} = jiffy:decode(Line, [return_maps]),
    {frame, T, [{Id, list_to_tuple(P), list_to_tuple(V), quat(B), wvec(B)}
                || #{<<"id">> := Id, <<"p">> := P, <<"v">> := V} = B <- Bodies]}.

quat(#{<<"q">> := [X, Y, Z, W]}) -> {{X, Y, Z}, W};
quat(_) -> undefined.

wvec(#{<<"w">> := W}) -> list_to_tuple(W);
wvec(_) -> undefined.
