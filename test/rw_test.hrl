%% Test helpers for the suites in test/ (the apps' EUnit modules define the
%% same macro themselves: rebar3 copies them to _build, away from this file).
%%
%% Every float comparison in the tests is bit for bit: on OTP 25 =:=,
%% ?assertEqual, lists:member and a float literal in a pattern take -0.0
%% for 0.0. Write -0.0 only as a float on its own and build terms around it
%% at run time: the OTP 25 compiler keeps one copy of literals that are =:=,
%% so {x, [0.0]} and {x, [-0.0]} in one module can become one of them
%% (test/rw_test_lib_tests.erl).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
