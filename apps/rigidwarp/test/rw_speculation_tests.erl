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

%% Sync points every stride, and every 512 substeps at least.
sync_stride_test() ->
    ?assertEqual(64, rw_speculation:sync_stride(64, 1)),
    ?assertEqual(512, rw_speculation:sync_stride(512, 1)),
    ?assertEqual(512, rw_speculation:sync_stride(64000, 1)),
    ?assertEqual(5120, rw_speculation:sync_stride(20970, 10)).

%% The guard: over the budget, half as far (whole substeps, one at least)
%% and collect; over three quarters, collect; under half of it, twice as
%% far up to the stride; in between, as before.
ahead_test() ->
    Budget = 1000,
    ?assertEqual({1000, true}, rw_speculation:ahead(1001, Budget, 2000, 2000, 10)),
    ?assertEqual({990, true}, rw_speculation:ahead(5000, Budget, 1990, 2000, 10)),
    ?assertEqual({10, true}, rw_speculation:ahead(5000, Budget, 10, 2000, 10)),
    ?assertEqual({10, true}, rw_speculation:ahead(5000, Budget, 30, 2000, 10)),
    ?assertEqual({800, true}, rw_speculation:ahead(1000, Budget, 800, 2000, 10)),
    ?assertEqual({800, true}, rw_speculation:ahead(751, Budget, 800, 2000, 10)),
    ?assertEqual({800, false}, rw_speculation:ahead(750, Budget, 800, 2000, 10)),
    ?assertEqual({800, false}, rw_speculation:ahead(500, Budget, 800, 2000, 10)),
    ?assertEqual({1600, false}, rw_speculation:ahead(499, Budget, 800, 2000, 10)),
    ?assertEqual({2000, false}, rw_speculation:ahead(0, Budget, 1600, 2000, 10)),
    ?assertEqual({2000, false}, rw_speculation:ahead(-50, Budget, 2000, 2000, 10)),
    %% from one substep back to the stride in a few looks
    Back = lists:foldl(fun(_, A) -> element(1, rw_speculation:ahead(0, Budget, A, 2000, 10)) end, 10, lists:seq(1, 8)),
    ?assertEqual(2000, Back).

%% Rounds of collections take a third of the time at most.
collect_pause_test() ->
    ?assertEqual(0, rw_speculation:collect_pause(0)),
    ?assertEqual(200, rw_speculation:collect_pause(100)).

%% The option is in MiB; left out, the default.
budget_bytes_test() ->
    ?assertEqual(3 * ?MIB, rw_speculation:budget_bytes(#{speculation_mb => 3})),
    ?assertEqual(rw_speculation:default_mb() * ?MIB, rw_speculation:budget_bytes(#{groups => false})).
