%% The machine baseline: it measures, and it leaves the schedulers as they were.
-module(rw_machine_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).

parallel_ms_restores_schedulers_test() ->
    Online = erlang:system_info(schedulers_online),
    ?assert(rw_machine:parallel_ms(1, 2) > 0),
    ?assertEqual(Online, erlang:system_info(schedulers_online)).

scaling_reports_every_pair_test() ->
    #{one_scheduler_ms := [A1, A2], two_schedulers_ms := [B1, B2], scaling := S, scaling_min := Min,
      scaling_max := Max} = rw_machine:scaling(2),
    ?assertBitwise(lists:sort([A1 / B1, A2 / B2]), [Min, Max]),
    ?assertBitwise((Min + Max) / 2, S).
