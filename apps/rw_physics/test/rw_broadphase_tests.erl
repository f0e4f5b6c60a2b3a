%% The broadphase with concrete numbers: what each test returns, the order
%% of the pairs, the edges of a reach, touching spans and boxes sharing
%% several cells. rw_physics_prop compares it with a test of every pair.
-module(rw_broadphase_tests).
-include_lib("eunit/include/eunit.hrl").

%% A sphere item of radius 0.5 reaching Reach.
s(Key, X, Y, Z, Reach) -> {X, Key, Y, Z, 0.5, Reach}.

nothing_to_pair_test() ->
    ?assertEqual([], rw_broadphase:sweep([], {distance, 1.0})),
    ?assertEqual([], rw_broadphase:sweep([s(a, 0.0, 0.0, 0.0, 2.0)], {skin, 0.1})),
    ?assertEqual([], rw_broadphase:sweep([], spans)),
    ?assertEqual([], rw_broadphase:grid(0, fun(_) -> error(no_box) end, 1.0)),
    ?assertEqual([], rw_broadphase:grid(1, fun(1) -> {{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}} end, 1.0)).

distance_test() ->
    Items = [s(3, 0.0, 0.0, 0.0, 2.0), s(1, 0.0, 1.2, 0.0, 2.0), s(2, 5.0, 0.0, 0.0, 2.0)],
    %% 1.2 apart: within 1.25 x the sum of radii (1.0), not within 1.0 x
    ?assertEqual([{{1, 3}, 1.2, 1.0}], rw_broadphase:sweep(Items, {distance, 1.25})),
    ?assertEqual([], rw_broadphase:sweep(Items, {distance, 1.0})).

skin_test() ->
    Items = [s(a, 0.0, 0.0, 0.0, 2.0), s(b, 1.1, 0.0, 0.0, 2.0)],
    ?assertEqual([{a, b}], rw_broadphase:sweep(Items, {skin, 0.2})),
    ?assertEqual([], rw_broadphase:sweep(Items, {skin, 0.05})).

%% The pairs come in the reverse of the order the sweep finds them: by the
%% first member's x (then key), then by the second's.
order_test() ->
    Items = [s(K, X, 0.0, 0.0, 10.0) || {K, X} <- [{4, 0.3}, {1, 0.0}, {3, 0.2}, {2, 0.2}]],
    Found = [{1, 2}, {1, 3}, {1, 4}, {2, 3}, {2, 4}, {3, 4}],
    ?assertEqual(lists:reverse(Found), rw_broadphase:sweep(Items, {skin, 0.0})).

%% A partner exactly at the reach along an axis is not sought: the reach
%% is a strict bound, and callers give one above their test's distance.
reach_is_strict_test() ->
    ?assertEqual([], rw_broadphase:sweep([s(a, 0.0, 0.0, 0.0, 1.0), s(b, 1.0, 0.0, 0.0, 1.0)], {distance, 2.0})),
    ?assertEqual([], rw_broadphase:sweep([s(a, 0.0, 0.0, 0.0, 1.0), s(b, 0.0, 0.0, -1.0, 1.0)], {distance, 2.0})),
    ?assertEqual([{{a, b}, 1.0, 1.0}],
                 rw_broadphase:sweep([s(a, 0.0, 0.0, 0.0, 1.5), s(b, 1.0, 0.0, 0.0, 1.5)], {distance, 2.0})).

%% Closed intervals: touching at one point overlaps.
spans_test() ->
    Spans = [{0.0, a, 1.0}, {1.0, b, 2.0}, {2.5, c, 2.5}, {2.0, d, 3.0}],
    ?assertEqual(lists:sort([{a, b}, {b, d}, {c, d}]), lists:sort(rw_broadphase:sweep(Spans, spans))).

%% Boxes that share two cells pair once; boxes in neighbouring cells do
%% not pair (the grid knows cells, not distances).
grid_test() ->
    Boxes = {{{0.1, 0.1, 0.1}, {1.5, 0.5, 0.5}},      % cells x 0 and 1
             {{0.2, 0.2, 0.2}, {1.2, 0.4, 0.4}},      % cells x 0 and 1
             {{2.1, 0.1, 0.1}, {2.5, 0.5, 0.5}},      % cell x 2
             {{1.9, 0.1, 0.1}, {2.0, 0.5, 0.5}}},     % cells x 1 and 2
    Pairs = rw_broadphase:grid(4, fun(K) -> element(K, Boxes) end, 1.0),
    ?assertEqual([{1, 2}, {1, 4}, {2, 4}, {3, 4}], lists:sort(Pairs)),
    ?assertEqual(4, length(Pairs)).
