%% The tests' own bitwise comparison must itself be able to fail: it tells
%% -0.0 from 0.0 and 1 from 1.0, and says where two terms first differ.
%%
%% Terms holding -0.0 are built at run time here (a -0.0 alone is safe as a
%% literal): OTP 25's compiler keeps one copy of literals that are =:=, so
%% {x, [0.0]} and {x, [-0.0]} written as two literals in one module may
%% both become the same one (checked: two such arguments of one call both
%% came out with -0.0).
-module(rw_test_lib_tests).
-include_lib("eunit/include/eunit.hrl").
-include("rw_test.hrl").

neg_zero() -> -0.0.

frame(Y) -> {frame, 0, [{<<"a">>, {Y, 1.0, 0.0}}]}.

signed_zeros_differ_test() ->
    Neg = neg_zero(),
    ?assert(0.0 =:= Neg),      % what OTP 25 does, and why the tests do not compare floats with =:=
    ?assertNot(rw_test_lib:bitwise_equal(0.0, Neg)),
    ?assertNot(rw_test_lib:bitwise_equal(frame(0.0), frame(Neg))),
    ?assert(rw_test_lib:bitwise_equal(frame(Neg), frame(neg_zero()))),
    ?assertNot(rw_test_lib:bitwise_equal(1, 1.0)),
    %% maps equal by content compare equal however they were built
    ?assert(rw_test_lib:bitwise_equal(#{a => 1.5, b => [0.0]}, maps:from_list([{b, [0.0]}, {a, 1.5}]))),
    ?assertBitwise({1.5, Neg}, {3.0 / 2, neg_zero()}).

assert_bitwise_fails_with_both_terms_and_the_path_test() ->
    Neg = neg_zero(),
    try rw_test_lib:assert_bitwise([{a, 1.0, {0.0, 2.0}}], [{a, 1.0, {Neg, 2.0}}], here) of
        ok -> ?assert(false)
    catch
        error:{assert_bitwise, Report} ->
            ?assertEqual(here, proplists:get_value(where, Report)),
            {Path, Expected, Got} = proplists:get_value(first_difference, Report),
            ?assertEqual([1, 3, 1], Path),
            ?assert(rw_test_lib:bitwise_equal(0.0, Expected)),
            ?assert(rw_test_lib:bitwise_equal(Neg, Got))
    end,
    ?assertEqual(none, rw_test_lib:first_difference({1.0, [2]}, {1.0, [2]})),
    ?assertEqual({[b], 1.0, 1}, rw_test_lib:first_difference(#{a => 0, b => 1.0}, #{a => 0, b => 1})),
    ?assertEqual({[], [1, 2], [1]}, rw_test_lib:first_difference([1, 2], [1])).
