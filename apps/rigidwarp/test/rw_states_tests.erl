-module(rw_states_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("rw_physics/include/rw_physics.hrl").

%% Awkward doubles: signed zeros, subnormals, huge, tiny, far coordinates.
specials() -> [0.0, -0.0, 5.0e-324, -2.2250738585072014e-308, 1.7976931348623157e308, 1.0e9 + 0.1, -3.5].

vec(K) -> {pick(K), pick(K + 1), pick(K + 2)}.
pick(K) ->
    case K rem 3 of
        0 -> lists:nth(K rem length(specials()) + 1, specials());
        _ -> (rand:uniform() - 0.5) * math:pow(10.0, rand:uniform(30) - 15)
    end.

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
                   %% =:= tells -0.0 from 0.0 and would see any rounding
                   ?assert(rw_states:state(Packed, I) =:= St),
                   ?assert(rw_states:position(Packed, I) =:= St#st.p),
                   ?assert(rw_states:displacement(Packed, I) =:= case Disps of
                                                                   undefined -> undefined;
                                                                   _ -> lists:nth(I, Disps)
                                                               end)
               end || {I, St} <- lists:zip(lists:seq(1, 40), States)]
      end} || Rot <- [false, true], Ccd <- [false, true]].

%% The point of packing: the states live off the process heap.
off_heap_test() ->
    {_, _, _, Bin} = rw_states:pack([state(K, false) || K <- lists:seq(1, 4)], undefined, false, false),
    ?assert(byte_size(Bin) > 64),
    ?assert(erts_debug:flat_size(Bin) < 10).
