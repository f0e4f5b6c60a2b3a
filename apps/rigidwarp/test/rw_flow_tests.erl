-module(rw_flow_tests).
-include_lib("eunit/include/eunit.hrl").

%% The window is bounded in frames and in bytes: a few dozen frames of a
%% small scene, a few of 20,000 bodies, never fewer than two.
window_test() ->
    ?assertEqual(64, rw_flow:window(500, frames)),
    ?assertEqual(64, rw_flow:window(20000, times)),
    ?assertEqual(6, rw_flow:window(20000, frames)),
    ?assertEqual(2, rw_flow:window(10000000, frames)),
    ?assertEqual(64, rw_flow:window(0, frames)).

%% GVT may go a window of frames past the latest delivered, less what the
%% slowest subscriber has not handled; without subscribers, anywhere.
allowance_test() ->
    ?assertEqual(100 + 4 * 10, rw_flow:allowance(100, [0], 4, 10)),
    ?assertEqual(100 + 1 * 10, rw_flow:allowance(100, [0, 3, 1], 4, 10)),
    ?assertEqual(100 - 2 * 10, rw_flow:allowance(100, [6], 4, 10)),
    ?assertEqual(rw_flow:unbounded(), rw_flow:allowance(100, [], 4, 10)).

%% The allowance moves by half a window at least, or when its bound comes
%% or goes; it is never taken back.
move_test() ->
    U = rw_flow:unbounded(),
    ?assertNot(rw_flow:move(100, 100, 8, 10)),
    ?assertNot(rw_flow:move(100, 130, 8, 10)),
    ?assert(rw_flow:move(100, 140, 8, 10)),
    ?assertNot(rw_flow:move(100, 60, 8, 10)),
    ?assert(rw_flow:move(U, 60, 8, 10)),
    ?assert(rw_flow:move(100, U, 8, 10)),
    ?assertNot(rw_flow:move(U, U, 8, 10)),
    %% a window of two moves a frame at a time
    ?assert(rw_flow:move(100, 110, 2, 10)).

held_test() ->
    ?assert(rw_flow:held(100, 100)),
    ?assertNot(rw_flow:held(90, 100)),
    ?assertNot(rw_flow:held(1 bsl 40, rw_flow:unbounded())).
