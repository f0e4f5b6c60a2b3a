%% Narrowphase with concrete numbers. Normals point from the sphere (or the
%% lower-index sphere) to the other body; depth is positive when overlapping.
-module(rw_narrow_tests).
-include_lib("eunit/include/eunit.hrl").
%% Bit for bit (test/rw_test.hrl has the same macro for the suites; rebar3
%% copies these modules to _build, away from it).
-define(assertBitwise(Expected, Actual), rw_test_lib:assert_bitwise(Expected, Actual, {?MODULE, ?LINE})).
-include("rw_physics.hrl").

-define(TOL, 1.0e-12).
-define(near(A, B), ?assert(abs((A) - (B)) =< ?TOL)).
-define(near_vec(A, B), ?assert(rw_vec:len(rw_vec:sub(A, B)) =< ?TOL)).

-define(FLOOR, {plane, {0.0, 1.0, 0.0}, 0.0}).
-define(CUBE, {box, {0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}, solid}).
-define(CAGE, {box, {0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}, hollow}).
%% axis z, radius 1, from z = -2 to z = 2
-define(CYL, {cylinder, {0.0, 0.0, 0.0}, {0.0, 0.0, 1.0}, 1.0, 2.0}).

one(P, R, Shape) ->
    [{0, C}] = rw_narrow:sphere_fixture(P, R, Shape),
    C.

%%% sphere-sphere

sphere_sphere_overlap_test() ->
    #contact{n = N, depth = D, toi = T} = rw_narrow:sphere_sphere({0.0, 0.0, 0.0}, 1.0, {1.5, 0.0, 0.0}, 1.0),
    ?near_vec({1.0, 0.0, 0.0}, N),
    ?near(0.5, D),
    ?assertBitwise(0.0, T).

sphere_sphere_3_4_5_test() ->
    %% centres 5 apart along (0.6, 0.8, 0), radii 2 and 4: depth 1
    #contact{n = N, depth = D} = rw_narrow:sphere_sphere({1.0, 2.0, 3.0}, 2.0, {4.0, 6.0, 3.0}, 4.0),
    ?near_vec({0.6, 0.8, 0.0}, N),
    ?near(1.0, D),
    %% the other way round the normal flips, the depth stays
    #contact{n = N2, depth = D2} = rw_narrow:sphere_sphere({4.0, 6.0, 3.0}, 4.0, {1.0, 2.0, 3.0}, 2.0),
    ?near_vec({-0.6, -0.8, 0.0}, N2),
    ?near(1.0, D2).

sphere_sphere_apart_or_touching_test() ->
    ?assertEqual(none, rw_narrow:sphere_sphere({0.0, 0.0, 0.0}, 1.0, {2.0, 0.0, 0.0}, 1.0)),   % touching only
    ?assertEqual(none, rw_narrow:sphere_sphere({0.0, 0.0, 0.0}, 1.0, {0.0, 0.0, -3.0}, 1.0)).

sphere_sphere_coincident_test() ->
    #contact{n = N, depth = D} = rw_narrow:sphere_sphere({1.0, 1.0, 1.0}, 1.0, {1.0, 1.0, 1.0}, 0.5),
    ?assertBitwise({0.0, 1.0, 0.0}, N),
    ?assertBitwise(1.5, D).

%%% planes

plane_floor_test() ->
    #contact{n = N, depth = D, toi = T} = one({3.0, 0.25, 0.0}, 0.5, ?FLOOR),
    ?near_vec({0.0, -1.0, 0.0}, N),
    ?near(0.25, D),
    ?assertBitwise(0.0, T),
    ?assertEqual([], rw_narrow:sphere_fixture({3.0, 0.5, 0.0}, 0.5, ?FLOOR)),      % touching only
    ?assertEqual([], rw_narrow:sphere_fixture({3.0, 7.0, 0.0}, 0.5, ?FLOOR)).

plane_tilted_test() ->
    %% 0.6 y + 0.8 z = 2
    Plane = {plane, {0.0, 0.6, 0.8}, 2.0},
    #contact{n = N, depth = D} = one({0.0, 0.6 * 2.3, 0.8 * 2.3}, 0.5, Plane),
    ?near_vec({0.0, -0.6, -0.8}, N),
    ?near(0.2, D),
    %% centre 1 behind the plane: depth is radius + 1
    #contact{depth = D2} = one({5.0, 0.6, 0.8}, 0.5, Plane),
    ?near(1.5, D2).

%%% cylinders

cylinder_side_test() ->
    #contact{n = N, depth = D} = one({1.4, 0.0, 0.5}, 0.5, ?CYL),
    ?near_vec({-1.0, 0.0, 0.0}, N),
    ?near(0.1, D).

cylinder_cap_test() ->
    #contact{n = N, depth = D} = one({0.0, 0.3, 2.2}, 0.5, ?CYL),
    ?near_vec({0.0, 0.0, -1.0}, N),
    ?near(0.3, D),
    #contact{n = N2, depth = D2} = one({0.2, 0.0, -2.4}, 0.5, ?CYL),
    ?near_vec({0.0, 0.0, 1.0}, N2),
    ?near(0.1, D2).

cylinder_rim_test() ->
    %% nearest point is the rim (1, 0, 2), 0.5 away along (-0.6, 0, -0.8)
    #contact{n = N, depth = D} = one({1.3, 0.0, 2.4}, 0.6, ?CYL),
    ?near_vec({-0.6, 0.0, -0.8}, N),
    ?near(0.1, D).

cylinder_inside_test() ->
    %% nearer the side than the caps: leave radially
    #contact{n = N, depth = D} = one({0.8, 0.0, 0.0}, 0.1, ?CYL),
    ?near_vec({-1.0, 0.0, 0.0}, N),
    ?near(0.3, D),
    %% nearer the top cap: leave upwards (the normal points down, into the body)
    #contact{n = N2, depth = D2} = one({0.0, 0.0, 1.9}, 0.1, ?CYL),
    ?near_vec({0.0, 0.0, -1.0}, N2),
    ?near(0.2, D2).

cylinder_on_axis_test() ->
    %% on the axis of an axis-aligned cylinder: any radial direction will do
    #contact{n = N, depth = D} = one({0.0, 0.0, 0.3}, 0.1, ?CYL),
    ?near(1.0, rw_vec:len(N)),
    ?near(0.0, rw_vec:dot(N, {0.0, 0.0, 1.0})),
    ?near(1.1, D).

%% The same on a tilted axis. The centre lies on the axis only up to
%% rounding, so the "radial" offset is rounding noise of ~1e-17; a side
%% contact must still have a normal perpendicular to the axis (otherwise the
%% sphere is pushed along the axis by the radial depth, and stays inside).
cylinder_on_tilted_axis_test() ->
    Axis = rw_vec:norm({1.0, 2.0, 3.0}),
    Cyl = {cylinder, {0.0, 0.0, 0.0}, Axis, 0.1, 1.0},
    P = rw_vec:scale(Axis, 0.3),
    #contact{n = N, depth = D} = one(P, 0.05, Cyl),
    ?near(0.15, D),
    ?assert(abs(rw_vec:dot(N, Axis)) =< 1.0e-9),
    %% pushed out against the normal by depth, it no longer touches
    ?assertEqual([], rw_narrow:sphere_fixture(rw_vec:madd(P, N, -(D + 1.0e-9)), 0.05, Cyl)).

cylinder_along_y_test() ->
    Cyl = {cylinder, {5.0, 5.0, 5.0}, {0.0, 1.0, 0.0}, 0.5, 1.0},
    #contact{n = N, depth = D} = one({5.0, 5.0, 5.9}, 0.5, Cyl),
    ?near_vec({0.0, 0.0, -1.0}, N),
    ?near(0.1, D),
    ?assertEqual([], rw_narrow:sphere_fixture({5.0, 6.6, 5.0}, 0.5, Cyl)),    % 0.6 above a cap
    ?assertEqual([], rw_narrow:sphere_fixture({3.0, 0.0, 0.0}, 0.5, ?CYL)).

%%% solid boxes

solid_box_face_test() ->
    #contact{n = N, depth = D} = one({1.3, 0.0, 0.0}, 0.5, ?CUBE),
    ?near_vec({-1.0, 0.0, 0.0}, N),
    ?near(0.2, D),
    ?assertEqual([], rw_narrow:sphere_fixture({2.0, 0.0, 0.0}, 0.5, ?CUBE)).

solid_box_edge_and_corner_test() ->
    #contact{n = N, depth = D} = one({1.3, 1.4, 0.0}, 0.6, ?CUBE),
    ?near_vec({-0.6, -0.8, 0.0}, N),
    ?near(0.1, D),
    #contact{n = N2, depth = D2} = one({1.2, -1.2, 1.2}, 0.5, ?CUBE),
    S = 1.0 / math:sqrt(3.0),
    ?near_vec({-S, S, -S}, N2),
    ?near(0.5 - 0.2 * math:sqrt(3.0), D2),
    ?assertEqual([], rw_narrow:sphere_fixture({1.3, 1.3, 1.3}, 0.5, ?CUBE)).   % 0.52 from the corner

solid_box_inside_test() ->
    %% centre inside: leave through the nearest face
    #contact{n = N, depth = D} = one({0.0, 0.9, 0.0}, 0.5, ?CUBE),
    ?assertBitwise({0.0, -1.0, 0.0}, N),
    ?near(0.6, D),
    #contact{n = N2, depth = D2} = one({-0.7, 0.2, 0.1}, 0.5, ?CUBE),
    ?assertBitwise({1.0, 0.0, 0.0}, N2),
    ?near(0.8, D2).

solid_box_centre_test() ->
    Box = {box, {2.0, 3.0, 4.0}, {1.0, 2.0, 3.0}, solid},
    #contact{n = N, depth = D} = one({2.0, 3.0, 4.0}, 0.5, Box),
    ?assertBitwise({-1.0, 0.0, 0.0}, N),          % the thinnest direction
    ?near(1.5, D),
    %% a cube's centre is equally deep on all faces: some face, unit normal
    #contact{n = N2, depth = D2} = one({0.0, 0.0, 0.0}, 0.5, ?CUBE),
    ?near(1.0, rw_vec:len(N2)),
    ?near(1.5, D2).

%%% hollow boxes (containers): each wall is its own feature

hollow_box_centre_test() ->
    ?assertEqual([], rw_narrow:sphere_fixture({0.0, 0.0, 0.0}, 0.5, ?CAGE)).

hollow_box_wall_test() ->
    [{1, #contact{n = N, depth = D}}] = rw_narrow:sphere_fixture({0.8, 0.0, 0.0}, 0.5, ?CAGE),
    ?near_vec({1.0, 0.0, 0.0}, N),
    ?near(0.3, D),
    [{2, #contact{n = N2, depth = D2}}] = rw_narrow:sphere_fixture({0.0, -0.9, 0.0}, 0.2, ?CAGE),
    ?near_vec({0.0, -1.0, 0.0}, N2),
    ?near(0.1, D2),
    Off = {box, {10.0, 0.0, 0.0}, {2.0, 1.0, 1.0}, hollow},
    [{1, #contact{depth = D3}}] = rw_narrow:sphere_fixture({11.5, 0.0, 0.0}, 0.6, Off),
    ?near(0.1, D3).

hollow_box_edge_test() ->
    [{1, #contact{n = NX, depth = DX}}, {3, #contact{n = NY, depth = DY}}] =
        rw_narrow:sphere_fixture({0.8, 0.8, 0.0}, 0.5, ?CAGE),
    ?near_vec({1.0, 0.0, 0.0}, NX),
    ?near_vec({0.0, 1.0, 0.0}, NY),
    ?near(0.3, DX),
    ?near(0.3, DY).

hollow_box_corner_test() ->
    Corner = rw_narrow:sphere_fixture({0.8, 0.7, -0.9}, 0.5, ?CAGE),
    ?assertEqual([1, 3, 4], [F || {F, _} <- Corner]),
    [{1, #contact{n = N1, depth = D1}}, {3, #contact{n = N3, depth = D3}}, {4, #contact{n = N4, depth = D4}}] = Corner,
    ?near_vec({1.0, 0.0, 0.0}, N1),
    ?near_vec({0.0, 1.0, 0.0}, N3),
    ?near_vec({0.0, 0.0, -1.0}, N4),
    ?near(0.3, D1),
    ?near(0.2, D3),
    ?near(0.4, D4).

%%% swept sphere-sphere

swept_head_on_test() ->
    %% 10 apart, radii 1 (gap 8), closing by 20 over the substep: 8 / 20
    #contact{n = N, depth = D, toi = T} =
        rw_narrow:swept_sphere_sphere({0.0, 0.0, 0.0}, {10.0, 0.0, 0.0}, 1.0, {10.0, 0.0, 0.0}, {-10.0, 0.0, 0.0}, 1.0),
    ?assertBitwise(0.4, T),
    ?assertBitwise({1.0, 0.0, 0.0}, N),
    ?assertBitwise(-8.0, D),
    %% only B moving: same
    #contact{toi = T2} =
        rw_narrow:swept_sphere_sphere({0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, 1.0, {10.0, 0.0, 0.0}, {-20.0, 0.0, 0.0}, 1.0),
    ?assertBitwise(0.4, T2).

swept_oblique_test() ->
    %% B passes 1 off A's centre: (10 - 20 s)^2 + 1 = 4
    #contact{n = N, toi = T} =
        rw_narrow:swept_sphere_sphere({0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, 1.0, {10.0, 1.0, 0.0}, {-20.0, 0.0, 0.0}, 1.0),
    ?near((10.0 - math:sqrt(3.0)) / 20.0, T),
    ?near_vec({math:sqrt(3.0) / 2.0, 0.5, 0.0}, N).

swept_misses_test() ->
    Z = {0.0, 0.0, 0.0},
    %% passes 2.5 off centre
    ?assertEqual(none, rw_narrow:swept_sphere_sphere(Z, Z, 1.0, {10.0, 2.5, 0.0}, {-20.0, 0.0, 0.0}, 1.0)),
    %% separating
    ?assertEqual(none, rw_narrow:swept_sphere_sphere(Z, {-10.0, 0.0, 0.0}, 1.0, {10.0, 0.0, 0.0}, Z, 1.0)),
    %% not moving
    ?assertEqual(none, rw_narrow:swept_sphere_sphere(Z, Z, 1.0, {10.0, 0.0, 0.0}, Z, 1.0)),
    %% closing, but only by 5 of the 8
    ?assertEqual(none, rw_narrow:swept_sphere_sphere(Z, {5.0, 0.0, 0.0}, 1.0, {10.0, 0.0, 0.0}, Z, 1.0)).

swept_already_overlapping_test() ->
    #contact{depth = D, toi = T} =
        rw_narrow:swept_sphere_sphere({0.0, 0.0, 0.0}, {5.0, 0.0, 0.0}, 1.0, {1.5, 0.0, 0.0}, {0.0, 0.0, 0.0}, 1.0),
    ?assertBitwise(0.0, T),
    ?near(0.5, D).

%%% swept fixtures

swept_plane_test() ->
    [{0, #contact{n = N, depth = D, toi = T}}] =
        rw_narrow:swept_sphere_fixture({0.0, 2.5, 0.0}, {1.0, -4.0, 0.0}, 0.5, ?FLOOR),
    ?assertBitwise(0.5, T),
    ?near_vec({0.0, -1.0, 0.0}, N),
    ?near(-2.0, D),
    ?assertEqual([], rw_narrow:swept_sphere_fixture({0.0, 2.5, 0.0}, {0.0, 4.0, 0.0}, 0.5, ?FLOOR)),   % going up
    ?assertEqual([], rw_narrow:swept_sphere_fixture({0.0, 2.5, 0.0}, {0.0, -1.5, 0.0}, 0.5, ?FLOOR)),  % short
    [{0, #contact{toi = T0, depth = D0}}] =
        rw_narrow:swept_sphere_fixture({0.0, 0.4, 0.0}, {0.0, -1.0, 0.0}, 0.5, ?FLOOR),             % already in
    ?assertBitwise(0.0, T0),
    ?near(0.1, D0).

swept_thin_wall_test() ->
    %% a 2 cm wall that a 5 cm sphere moving 10 m per substep would skip
    Wall = {box, {10.0, 0.0, 0.0}, {0.01, 2.0, 2.0}, solid},
    ?assertEqual([], rw_narrow:sphere_fixture({5.0, 0.0, 0.0}, 0.05, Wall)),
    ?assertEqual([], rw_narrow:sphere_fixture({15.0, 0.0, 0.0}, 0.05, Wall)),
    [{0, #contact{n = N, depth = D, toi = T}}] =
        rw_narrow:swept_sphere_fixture({5.0, 0.0, 0.0}, {10.0, 0.0, 0.0}, 0.05, Wall),
    ?near((10.0 - 0.01 - 0.05 - 5.0) / 10.0, T),
    ?assertBitwise({1.0, 0.0, 0.0}, N),
    ?near(-4.94, D),
    %% from the other side
    [{0, #contact{n = N2, toi = T2}}] =
        rw_narrow:swept_sphere_fixture({15.0, 0.0, 0.0}, {-10.0, 0.0, 0.0}, 0.05, Wall),
    ?near((15.0 - 10.01 - 0.05) / 10.0, T2),
    ?assertBitwise({-1.0, 0.0, 0.0}, N2),
    %% beside it
    ?assertEqual([], rw_narrow:swept_sphere_fixture({5.0, 3.0, 0.0}, {10.0, 0.0, 0.0}, 0.05, Wall)).

swept_cage_wall_test() ->
    %% from the centre towards the +x wall: the sphere's surface reaches it
    %% after 0.5 of the 2 m
    [{1, #contact{n = N, toi = T}}] = rw_narrow:swept_sphere_fixture({0.0, 0.0, 0.0}, {2.0, 0.0, 0.0}, 0.5, ?CAGE),
    ?assertBitwise(0.25, T),
    ?near_vec({1.0, 0.0, 0.0}, N).

swept_cylinder_test() ->
    %% sampled: reports the first sample that overlaps, so toi is at most one
    %% sample (a quarter radius of path) after the true touch at 4.25 / 10
    Cyl = {cylinder, {5.0, 0.0, 0.0}, {0.0, 0.0, 1.0}, 0.5, 1.0},
    ?assertEqual([], rw_narrow:sphere_fixture({0.0, 0.0, 0.0}, 0.25, Cyl)),
    [{0, #contact{n = N, toi = T}}] = rw_narrow:swept_sphere_fixture({0.0, 0.0, 0.0}, {10.0, 0.0, 0.0}, 0.25, Cyl),
    ?assert(T > 0.425 andalso T =< 0.425 + 0.0625 / 10.0 + 1.0e-12),
    ?near_vec({1.0, 0.0, 0.0}, N),
    ?assertEqual([], rw_narrow:swept_sphere_fixture({0.0, 2.0, 0.0}, {10.0, 0.0, 0.0}, 0.25, Cyl)).

%%% segment against box (slab test)

-define(LO, {-1.0, -1.0, -1.0}).
-define(HI, {1.0, 1.0, 1.0}).

segment_box_enters_through_a_face_test() ->
    ?assertEqual({0.25, 0}, rw_narrow:segment_box({-2.0, 0.0, 0.0}, {4.0, 0.0, 0.0}, ?LO, ?HI, closed)),
    ?assertEqual({0.25, 0}, rw_narrow:segment_box({-2.0, 0.0, 0.0}, {4.0, 0.0, 0.0}, ?LO, ?HI, open)),
    %% the last slab entered names the face
    ?assertEqual({0.5, 1}, rw_narrow:segment_box({-1.5, -2.0, 0.0}, {2.0, 2.0, 0.0}, ?LO, ?HI, closed)).

segment_box_starting_inside_test() ->
    ?assertEqual({0.0, none}, rw_narrow:segment_box({0.0, 0.0, 0.0}, {5.0, 0.0, 0.0}, ?LO, ?HI, closed)),
    ?assertEqual({0.0, none}, rw_narrow:segment_box({0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, ?LO, ?HI, open)).

segment_box_misses_test() ->
    ?assertEqual(none, rw_narrow:segment_box({-2.0, 0.0, 0.0}, {0.5, 0.0, 0.0}, ?LO, ?HI, closed)),
    ?assertEqual(none, rw_narrow:segment_box({-2.0, 3.0, 0.0}, {4.0, 0.0, 0.0}, ?LO, ?HI, closed)),
    ?assertEqual(none, rw_narrow:segment_box({-2.0, 0.0, 0.0}, {4.0, 6.0, 0.0}, ?LO, ?HI, closed)).

%% Touching the surface meets the closed box, not the open one: ending on
%% a face, or gliding along one.
segment_box_surface_test() ->
    ?assertEqual({1.0, 0}, rw_narrow:segment_box({-2.0, 0.0, 0.0}, {1.0, 0.0, 0.0}, ?LO, ?HI, closed)),
    ?assertEqual(none, rw_narrow:segment_box({-2.0, 0.0, 0.0}, {1.0, 0.0, 0.0}, ?LO, ?HI, open)),
    ?assertEqual({0.25, 0}, rw_narrow:segment_box({-2.0, 1.0, 0.0}, {4.0, 0.0, 0.0}, ?LO, ?HI, closed)),
    ?assertEqual(none, rw_narrow:segment_box({-2.0, 1.0, 0.0}, {4.0, 0.0, 0.0}, ?LO, ?HI, open)).

%% On random segments the open box meets only what the closed box meets,
%% at the same place, and both agree with points sampled along the segment.
segment_box_random_test() ->
    Rand0 = rand:seed_s(exsss, 7),
    lists:foldl(fun(_, R0) ->
                        {[PX, PY, PZ, DX, DY, DZ], R1} = uniforms(6, R0, []),
                        P = {4.0 * PX - 2.0, 4.0 * PY - 2.0, 4.0 * PZ - 2.0},
                        D = {4.0 * DX - 2.0, 4.0 * DY - 2.0, 4.0 * DZ - 2.0},
                        Closed = rw_narrow:segment_box(P, D, ?LO, ?HI, closed),
                        Open = rw_narrow:segment_box(P, D, ?LO, ?HI, open),
                        ?assert(Open =:= none orelse Open =:= Closed),
                        Inside = [S || S <- [I / 64 || I <- lists:seq(0, 64)],
                                       strictly_inside(rw_vec:madd(P, D, S))],
                        Inside =:= [] orelse ?assertNotEqual(none, Open),
                        R1
                end, Rand0, lists:seq(1, 2000)),
    ok.

uniforms(0, R, Acc) -> {Acc, R};
uniforms(N, R0, Acc) ->
    {X, R1} = rand:uniform_s(R0),
    uniforms(N - 1, R1, [X | Acc]).

strictly_inside({X, Y, Z}) -> abs(X) < 1.0 andalso abs(Y) < 1.0 andalso abs(Z) < 1.0.
