-module(rw_states_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include_lib("rw_physics/include/rw_physics.hrl").

%% Awkward doubles: signed zeros, subnormals, huge, tiny, far coordinates.
specials() -> [0.0, -0.0, 5.0e-324, -2.2250738585072014e-308, 1.7976931348623157e308, 1.0e9 + 0.1, -3.5].

vec(K) -> {pick(K), pick(K + 1), pick(K + 2)}.
pick(K) ->
    case K rem 3 of
        0 -> lists:nth(K rem length(specials()) + 1, specials());
        _ -> (rand:uniform() - 0.5) * math:pow(10.0, rand:uniform(30) - 15)
    end.

%% Bit for bit the same terms (on OTP 25, =:= takes -0.0 for 0.0).
same(A, B) -> rw_test_lib:bitwise_equal(A, B).

state(K, false) -> #st{p = vec(K), v = vec(K + 3)};
state(K, true) -> #st{p = vec(K), v = vec(K + 3), q = {vec(K + 6), pick(K + 9)}, w = vec(K + 10)}.

round_trip_test_() ->
    [{lists:flatten(io_lib:format("rotation ~p, ccd ~p", [Rot, Ccd])),
      fun() ->
              States = [state(K, Rot) || K <- lists:seq(1, 40)],
              Disps = case Ccd of true -> [vec(K + 20) || K <- lists:seq(1, 40)]; false -> undefined end,
              Packed = rw_states:pack(States, Disps, Rot, Ccd),
              ?assertEqual(40, rw_states:count(Packed)),
              [begin
                   %% same/2 tells -0.0 from 0.0 and would see any rounding
                   ?assert(same(rw_states:state(Packed, I), St)),
                   ?assert(same(rw_states:position(Packed, I), St#st.p)),
                   ?assert(same(rw_states:displacement(Packed, I), case Disps of
                                                                      undefined -> undefined;
                                                                      _ -> lists:nth(I, Disps)
                                                                  end))
               end || {I, St} <- lists:zip(lists:seq(1, 40), States)]
      end} || Rot <- [false, true], Ccd <- [false, true]].

%% A group appends its states one by one and seals them: the same packed
%% states, extents and reach, bit for bit, as packing the list.
append_seal_is_pack_test_() ->
    [{lists:flatten(io_lib:format("rotation ~p, ccd ~p", [Rot, Ccd])),
      fun() ->
              [begin
                   States = [state(K + Offset, Rot) || K <- lists:seq(1, N)],
                   Disps = case Ccd of true -> [vec(K + 20) || K <- lists:seq(1, N)]; false -> undefined end,
                   Appended = lists:foldl(fun({K, St}, B) ->
                                                  D = case Disps of undefined -> undefined; _ -> lists:nth(K, Disps) end,
                                                  rw_states:append(B, St, D, Rot)
                                          end, <<>>, lists:zip(lists:seq(1, N), States)),
                   ?assert(same(rw_states:seal(Appended, Rot, Ccd), rw_states:pack(States, Disps, Rot, Ccd)))
               end || N <- [1, 2, 7, 40], Offset <- lists:seq(0, 5)]
      end} || Rot <- [false, true], Ccd <- [false, true]].

%% The point of packing: the states live off the process heap.
off_heap_test() ->
    {_, _, _, Bin, _, _} = rw_states:pack([state(K, false) || K <- lists:seq(1, 4)], undefined, false, false),
    ?assert(byte_size(Bin) > 64),
    ?assert(erts_debug:flat_size(Bin) < 10).

%% first_touch/6 skips substeps at which two bodies are too far apart to
%% touch: it must find exactly the offset a check of every substep finds,
%% with its C loop (rw_native) and in Erlang alone.
%% Straight approaches at full reach are the tight case (one substep
%% skipped too many misses the touch); random walks, bodies at rest, far
%% coordinates and touches at the very first or last substep cover the rest.
first_touch_equals_every_substep_test() ->
    _ = rand:seed(exsss, {7, 11, 13}),
    Cases = [touch_case(K) || K <- lists:seq(1, 3000)],
    Results = [{first_touch(C), brute_touch(C)} || C <- Cases],
    [?assertEqual(Brute, Skipping) || {Skipping, Brute} <- Results],
    %% the scan in C (rw_native) and in Erlang alone
    ok = rw_native:use(false),
    InErlang = try [first_touch(C) || C <- Cases] after ok = rw_native:use(true) end,
    ?assertEqual([Brute || {_, Brute} <- Results], InErlang),
    %% the cases do touch, at many different offsets, and sometimes not
    Offsets = lists:usort([K || {K, _} <- Results]),
    ?assert(lists:member(none, Offsets)),
    ?assert(lists:member(0, Offsets)),
    ?assert(length(Offsets) > 40).

touch_case(K) ->
    N = 1 + rand:uniform(80),
    Offset = case K rem 5 of
                 0 -> 1.0e9 * (rand:uniform() - 0.5);
                 _ -> 0.0
             end,
    Start = {Offset + 10.0 * rand:uniform(), Offset, Offset},
    Step = rand:uniform() * math:pow(10.0, rand:uniform(4) - 3),
    {PathA, PathB} =
        case K rem 4 of
            0 -> {line(Start, {-Step, 0.0, 0.0}, N), line({Offset, Offset, Offset}, {0.0, 0.0, 0.0}, N)};
            1 -> {line(Start, {-Step, 0.0, 0.0}, N), line({Offset, Offset, Offset}, {Step, 0.0, 0.0}, N)};
            2 -> {walk(Start, Step, N), walk({Offset, Offset, Offset}, Step, N)};
            3 -> {line(Start, {0.0, 0.0, 0.0}, N), line({Offset, Offset, Offset}, {0.0, 0.0, 0.0}, N)}
        end,
    %% a sum of radii met somewhere along the paths, or missed by a hair
    Dists = [dist(A, B) || {A, B} <- lists:zip(PathA, PathB)],
    Sum = lists:nth(rand:uniform(N), Dists) * (1.0 + (rand:uniform() - 0.5) * 1.0e-12),
    IA = rand:uniform(N), IB = IA,
    {PathA, PathB, IA, IB, N - IA, Sum}.

line(P, D, N) -> [rw_vec:madd(P, D, float(I)) || I <- lists:seq(0, N - 1)].

walk(P, Step, N) ->
    lists:reverse(lists:foldl(fun(_, [Q | _] = Acc) ->
                                      Dir = rw_vec:norm({rand:normal(), rand:normal(), rand:normal()}),
                                      [rw_vec:madd(Q, Dir, Step * rand:uniform()) | Acc]
                              end, [P], lists:seq(2, N))).

dist(A, B) -> rw_vec:len(rw_vec:sub(A, B)).

packed(Path) -> rw_states:pack([#st{p = P, v = {0.0, 0.0, 0.0}} || P <- Path], undefined, false, false).

first_touch({PathA, PathB, IA, IB, Left, Sum}) ->
    rw_states:first_touch(packed(PathA), IA, packed(PathB), IB, Left, Sum).

brute_touch({PathA, PathB, IA, IB, Left, Sum}) ->
    Pairs = lists:zip(lists:nthtail(IA - 1, PathA), lists:nthtail(IB - 1, PathB)),
    Touch = [K || {K, {{XA, YA, ZA}, {XB, YB, ZB}}} <- lists:zip(lists:seq(0, length(Pairs) - 1), Pairs),
                  K =< Left,
                  (XB - XA) * (XB - XA) + (YB - YA) * (YB - YA) + (ZB - ZA) * (ZB - ZA) < Sum * Sum],
    case Touch of
        [] -> none;
        [K | _] -> K
    end.

%% Packing measures the positions' box and the largest move between two
%% states, for every layout.
extents_and_reach_test() ->
    _ = rand:seed(exsss, {1, 2, 3}),
    [begin
         Path = walk({1.0e9 * rand:uniform(), 0.0, -3.0}, rand:uniform(), 30),
         States = [state(K, Rot) || K <- lists:seq(1, 30)],
         Placed = [St#st{p = P} || {St, P} <- lists:zip(States, Path)],
         Disps = case Ccd of true -> [vec(K) || K <- lists:seq(1, 30)]; false -> undefined end,
         Packed = rw_states:pack(Placed, Disps, Rot, Ccd),
         Reach = rw_states:reach(Packed),
         Moves = [dist(A, B) || {A, B} <- lists:zip(lists:droplast(Path), tl(Path))],
         ?assert(Reach >= lists:max(Moves)),
         ?assert(Reach =< 1.8 * lists:max(Moves)),
         Coord = fun(I) -> [element(I, P) || P <- Path] end,
         ?assertBitwise({lists:min(Coord(1)), lists:min(Coord(2)), lists:min(Coord(3)),
                         lists:max(Coord(1)), lists:max(Coord(2)), lists:max(Coord(3))}, rw_states:extents(Packed)),
         [?assert(same(rw_states:state(Packed, I), St)) || {I, St} <- lists:zip(lists:seq(1, 30), Placed)]
     end || _ <- lists:seq(1, 50), Rot <- [false, true], Ccd <- [false, true]],
    Still = [#st{p = {1.0, 2.0, 3.0}, v = {0.0, 0.0, 0.0}}],
    ?assertBitwise(0.0, rw_states:reach(rw_states:pack(Still ++ Still, undefined, false, false))),
    ?assertBitwise(0.0, rw_states:reach(rw_states:pack(Still, undefined, false, false))),
    ?assertBitwise({1.0, 2.0, 3.0, 1.0, 2.0, 3.0}, rw_states:extents(rw_states:pack(Still, undefined, false, false))).

%% A move between coordinates near the largest double overflows: packing
%% still works, without a reach, and the scan then checks every substep.
no_reach_near_the_largest_double_test() ->
    Far = [#st{p = {X, 0.0, 0.0}, v = {0.0, 0.0, 0.0}} || X <- [1.7e308, -1.7e308, 1.7e308]],
    Near = [#st{p = {0.0, Y, 0.0}, v = {0.0, 0.0, 0.0}} || Y <- [0.0, 5.0, 0.5]],
    P = rw_states:pack(Far, undefined, false, false),
    ?assertEqual(undefined, rw_states:reach(P)),
    ?assertBitwise({-1.7e308, 0.0, 0.0, 1.7e308, 0.0, 0.0}, rw_states:extents(P)),
    [?assert(same(rw_states:state(P, I), St)) || {I, St} <- lists:zip([1, 2, 3], Far)],
    ?assert(same(rw_states:seal(element(4, P), false, false), P)),
    Q = rw_states:pack(Near, undefined, false, false),
    ?assertBitwise(5.0, rw_states:reach(Q)),
    ?assertEqual(0, rw_states:first_touch(Q, 1, Q, 1, 2, 1.0)),
    AtRest = rw_states:pack(lists:duplicate(3, hd(Near)), undefined, false, false),
    ?assertEqual(1, rw_states:first_touch(Q, 2, AtRest, 2, 1, 1.0)),
    ?assertEqual(none, rw_states:first_touch(Q, 2, AtRest, 2, 0, 1.0)),
    ?assertEqual(0, rw_states:first_touch(P, 2, P, 2, 1, 1.0)).
