%% Narrowphase and response with concrete numbers.
-module(rw_narrow_tests).
-include_lib("eunit/include/eunit.hrl").
-include("rw_physics.hrl").

-define(near(A, B), ?assert(abs((A) - (B)) < 1.0e-12)).

sphere_sphere_test() ->
    #contact{n = {1.0, 0.0, 0.0}, depth = D, toi = 0.0} = rw_narrow:sphere_sphere({0.0, 0.0, 0.0}, 1.0, {1.5, 0.0, 0.0}, 1.0),
    ?near(0.5, D),
    none = rw_narrow:sphere_sphere({0.0, 0.0, 0.0}, 1.0, {2.0, 0.0, 0.0}, 1.0),   % touching is not overlapping
    #contact{n = {0.0, 1.0, 0.0}} = rw_narrow:sphere_sphere({1.0, 1.0, 1.0}, 1.0, {1.0, 1.0, 1.0}, 1.0).

swept_sphere_sphere_test() ->
    %% 10 apart (gap 8), closing by 20 over the substep: touch at 8/20
    #contact{toi = Toi, n = {1.0, 0.0, 0.0}} =
        rw_narrow:swept_sphere_sphere({0.0, 0.0, 0.0}, {10.0, 0.0, 0.0}, 1.0, {10.0, 0.0, 0.0}, {-10.0, 0.0, 0.0}, 1.0),
    ?near(0.4, Toi),
    none = rw_narrow:swept_sphere_sphere({0.0, 0.0, 0.0}, {-10.0, 0.0, 0.0}, 1.0, {10.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, 1.0),
    none = rw_narrow:swept_sphere_sphere({0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, 1.0, {10.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, 1.0).

plane_test() ->
    Floor = {plane, {0.0, 1.0, 0.0}, 0.0},
    [{0, #contact{n = {0.0, -1.0, 0.0}, depth = D}}] = rw_narrow:sphere_fixture({3.0, 0.25, 0.0}, 0.5, Floor),
    ?near(0.25, D),
    [] = rw_narrow:sphere_fixture({3.0, 0.5, 0.0}, 0.5, Floor),
    [{0, #contact{toi = Toi}}] = rw_narrow:swept_sphere_fixture({0.0, 2.5, 0.0}, {0.0, -4.0, 0.0}, 0.5, Floor),
    ?near(0.5, Toi).

cylinder_test() ->
    Cyl = {cylinder, {0.0, 0.0, 0.0}, {0.0, 0.0, 1.0}, 1.0, 2.0},
    %% beside the curved side
    [{0, #contact{n = {-1.0, 0.0, 0.0}, depth = D1}}] = rw_narrow:sphere_fixture({1.4, 0.0, 0.5}, 0.5, Cyl),
    ?near(0.1, D1),
    %% above a cap
    [{0, #contact{n = {0.0, 0.0, -1.0}, depth = D2}}] = rw_narrow:sphere_fixture({0.0, 0.3, 2.2}, 0.5, Cyl),
    ?near(0.3, D2),
    %% inside, nearer the side than the caps
    [{0, #contact{n = {-1.0, 0.0, 0.0}, depth = D3}}] = rw_narrow:sphere_fixture({0.8, 0.0, 0.0}, 0.1, Cyl),
    ?near(0.3, D3),
    [] = rw_narrow:sphere_fixture({3.0, 0.0, 0.0}, 0.5, Cyl).

boxes_test() ->
    Solid = {box, {0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}, solid},
    [{0, #contact{n = {-1.0, 0.0, 0.0}, depth = D1}}] = rw_narrow:sphere_fixture({1.3, 0.0, 0.0}, 0.5, Solid),
    ?near(0.2, D1),
    %% centre inside: leave through the nearest face (+y)
    [{0, #contact{n = {0.0, -1.0, 0.0}, depth = D2}}] = rw_narrow:sphere_fixture({0.0, 0.9, 0.0}, 0.5, Solid),
    ?near(0.6, D2),
    Cage = {box, {0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}, hollow},
    [] = rw_narrow:sphere_fixture({0.0, 0.0, 0.0}, 0.5, Cage),
    %% a corner touches three walls, each its own feature
    Corner = rw_narrow:sphere_fixture({0.8, 0.8, -0.8}, 0.5, Cage),
    ?assertEqual([1, 3, 4], [F || {F, _} <- Corner]),
    [{1, #contact{n = {1.0, 0.0, 0.0}}}, {3, #contact{n = {0.0, 1.0, 0.0}}}, {4, #contact{n = {0.0, 0.0, -1.0}}}] = Corner.

thin_wall_swept_test() ->
    Wall = {box, {10.0, 0.0, 0.0}, {0.01, 2.0, 2.0}, solid},
    [] = rw_narrow:sphere_fixture({5.0, 0.0, 0.0}, 0.05, Wall),
    [{0, #contact{n = {1.0, 0.0, 0.0}, toi = Toi}}] = rw_narrow:swept_sphere_fixture({5.0, 0.0, 0.0}, {10.0, 0.0, 0.0}, 0.05, Wall),
    ?near((10.0 - 0.01 - 0.05 - 5.0) / 10.0, Toi).
