-module(rw_frames_tests).
-include_lib("eunit/include/eunit.hrl").

%% Awkward doubles: signed zeros, subnormals, the extremes, tiny and far
%% coordinates.
specials() -> [0.0, -0.0, 5.0e-324, -2.2250738585072014e-308, 1.7976931348623157e308, 1.0e9 + 0.1, -3.5, 1.0e-4,
               -9.88439599645466e-4, 123456789012345680.0].

pick(K) ->
    Specials = specials(),
    case K rem 3 of
        0 -> lists:nth(K rem length(Specials) + 1, Specials);
        _ -> (rand:uniform() - 0.5) * math:pow(10.0, rand:uniform(40) - 20)
    end.

vec(K) -> {pick(K), pick(K + 1), pick(K + 2)}.

frame(T, N) ->
    {frame, T, [case K rem 2 of
                    0 -> {<<"s", (integer_to_binary(K))/binary>>, vec(K), vec(K + 3), undefined, undefined};
                    1 -> {<<"r\"\\", (integer_to_binary(K))/binary>>, vec(K), vec(K + 3), {vec(K + 6), pick(K + 9)},
                          vec(K + 10)}
                end || K <- lists:seq(1, N)]}.

%% Bit for bit the same terms (on OTP 25, =:= takes -0.0 for 0.0).
same(A, B) -> rw_test_lib:bitwise_equal(A, B).

%% Every double comes back bit for bit, and a generic JSON decoder (jiffy)
%% reads a line as the object the format describes. (jiffy's own encoder
%% writes -0.0 as 0.0 and 5.0e-324 as 5e-324, which reads back as 0.0.)
round_trip_test() ->
    [begin
         Frame = frame(T, 200),
         Line = iolist_to_binary(rw_frames:encode(Frame)),
         ?assertEqual($\n, binary:last(Line)),
         ?assert(same(Frame, rw_frames:decode(Line))),
         {frame, _, Bodies} = Frame,
         Object = #{<<"t">> => T, <<"bodies">> => [generic(B) || B <- Bodies]},
         ?assert(same(Object, jiffy:decode(Line, [return_maps])))
     end || T <- [0, 10, 2.5, 1.0e-3]].

generic({Id, P, V, undefined, undefined}) ->
    #{<<"id">> => Id, <<"p">> => tuple_to_list(P), <<"v">> => tuple_to_list(V)};
generic({Id, P, V, {QV, QW}, W}) ->
    #{<<"id">> => Id, <<"p">> => tuple_to_list(P), <<"v">> => tuple_to_list(V),
      <<"q">> => tuple_to_list(QV) ++ [QW], <<"w">> => tuple_to_list(W)}.

%% An empty frame is still one valid line.
empty_frame_test() ->
    ?assertEqual(<<"{\"t\":5,\"bodies\":[]}\n">>, iolist_to_binary(rw_frames:encode({frame, 5, []}))).
