-module(rw_place_tests).
-include_lib("eunit/include/eunit.hrl").

%% Two columns along x, 10 m apart: cut between them, whatever else spreads.
columns_split_along_the_widest_axis_test() ->
    Ps = [{X, Y, 0.0} || X <- [-10.0, -8.5, 0.0, 1.5], Y <- [0.0, 1.5, 3.0]],
    Place = rw_place:new(Ps, 2, 4, 2.5),
    ?assertEqual([0, 0, 1, 1], [rw_place:site_of({X, 0.0, 0.0}, Place) || X <- [-10.0, -8.5, 0.0, 1.5]]),
    ?assertEqual(8, rw_place:buckets(Place)),
    %% the cut lies halfway through the gap: the cells a body's writes reach
    %% on either side of it are its own node's
    [?assertEqual(rw_place:site_of({X, 0.0, 0.0}, Place), rw_place:site_of({X + D, 0.0, 0.0}, Place))
     || X <- [-10.0, -8.5, 0.0, 1.5], D <- [-2.5, 2.5]].

%% Equal shares, never cutting a cell, every site's buckets its own.
shares_are_even_and_buckets_stay_home_test() ->
    Ps = [{float(I) * 0.37, float(I rem 7), 0.0} || I <- lists:seq(1, 300)],
    Cell = 1.0,
    [begin
         Place = rw_place:new(Ps, K, 5, Cell),
         Shares = rw_place:split([{I, P} || {I, P} <- lists:zip(lists:seq(1, 300), Ps)], Place),
         ?assertEqual(K, length(Shares)),
         ?assertEqual(300, length(lists:append(Shares))),
         [?assert(abs(length(S) - 300 / K) =< 300 / K / 2 + 3) || S <- Shares],
         [begin
              Site = rw_place:site_of(P, Place),
              Cellc = {floor(X / Cell), floor(Y / Cell), 0},
              B = rw_place:bucket(Cellc, Place),
              ?assert(B >= Site * 5 andalso B < Site * 5 + 5)
          end || {X, Y, _} = P <- Ps]
     end || K <- [1, 2, 3, 5]].

%% All bodies in one cell: the first site takes them, the others none.
one_cell_test() ->
    Ps = [{0.1, 0.2, 0.3} || _ <- lists:seq(1, 10)],
    Place = rw_place:new(Ps, 3, 2, 5.0),
    ?assertEqual([10, 0, 0], [length(S) || S <- rw_place:split([{I, P} || {I, P} <- lists:zip(lists:seq(1, 10), Ps)], Place)]).

%% Far coordinates (bignum cells) place as near ones.
far_away_test() ->
    Ps = [{1.0e300 + float(I) * 1.0e290, 0.0, 0.0} || I <- lists:seq(1, 4)],
    Place = rw_place:new(Ps, 2, 2, 1.0),
    ?assertEqual([0, 0, 1, 1], [rw_place:site_of(P, Place) || P <- Ps]).
