%% rw_speculation:stride/4: the stride a run's bodies step ahead of GVT
%% by under its memory budget.
-module(rw_speculation_tests).
-include_lib("eunit/include/eunit.hrl").

-define(MIB, (1 bsl 20)).

%% Within the budget the scene's stride stands.
fits_test() ->
    ?assertEqual(64, rw_speculation:stride(1024 * ?MIB, 500, 1, 64)),
    ?assertEqual(128, rw_speculation:stride(1024 * ?MIB, 0, 1, 128)).

%% stack_1000 at a 1 us substep (1 us ticks): the scene's 64 ms is 64,000
%% substeps a body; 1 GiB holds 2097 of them for 1000 bodies.
throttled_test() ->
    B = rw_speculation:bytes_per_body_substep(),
    Want = (1024 * ?MIB) div (1000 * B),
    ?assert(Want < 64000),
    ?assertEqual(Want, rw_speculation:stride(1024 * ?MIB, 1000, 1, 64000)),
    %% the same in ticks of 10 us per substep: whole substeps
    ?assertEqual(10 * Want, rw_speculation:stride(1024 * ?MIB, 1000, 10, 640000)).

%% One substep at least, however small the budget; never past the scene's
%% stride, however large.
bounds_test() ->
    ?assertEqual(7, rw_speculation:stride(1, 20000, 7, 7 * 64)),
    ?assertEqual(7 * 64, rw_speculation:stride(1 bsl 40, 1, 7, 7 * 64)).

%% Over a grid of budgets, bodies, substeps and strides: a whole number of
%% substeps, between one and the scene's stride, whose history fits the
%% budget unless it is the one substep; longer with more budget and
%% shorter with more bodies.
grid_test() ->
    B = rw_speculation:bytes_per_body_substep(),
    Budgets = [?MIB, 64 * ?MIB, 1024 * ?MIB, 4096 * ?MIB],
    Bodies = [1, 2, 300, 1000, 20000],
    Cases = [{Budget, N, Dt, Dt * K} || Budget <- Budgets, N <- Bodies, Dt <- [1, 10, 1000], K <- [1, 64, 64000]],
    [begin
         S = rw_speculation:stride(Budget, N, Dt, Stride),
         ?assertEqual(0, S rem Dt),
         ?assert(S >= Dt andalso S =< Stride),
         ?assert(S =:= Dt orelse (S div Dt) * N * B =< Budget),
         ?assert(S =:= Stride orelse ((S div Dt) + 1) * N * B > Budget),
         ?assert(rw_speculation:stride(2 * Budget, N, Dt, Stride) >= S),
         ?assert(rw_speculation:stride(Budget, 2 * N, Dt, Stride) =< S)
     end || {Budget, N, Dt, Stride} <- Cases],
    ok.

%% The option is in MiB; left out, the default.
budget_bytes_test() ->
    ?assertEqual(3 * ?MIB, rw_speculation:budget_bytes(#{speculation_mb => 3})),
    ?assertEqual(rw_speculation:default_mb() * ?MIB, rw_speculation:budget_bytes(#{groups => false})).
