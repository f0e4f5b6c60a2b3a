%% The cap on the cells a swept sphere lists in a substep: a move past it
%% raises at once instead of listing them, a move within it lists them,
%% and sweep_bound/4 (what validation checks a scene's speeds with) never
%% lets through a move that the cap refuses.
-module(rw_hash_tests).
-include_lib("eunit/include/eunit.hrl").

-define(ORIGIN, {0.0, 0.0, 0.0}).

%% Run F in a process whose heap may not pass 20 million words (160 MB):
%% a sweep that lists its cells before counting them is killed, not left
%% to fill the machine.
bounded(F) ->
    {Pid, Ref} = spawn_opt(fun() -> exit({result, catch F()}) end,
                           [monitor, {max_heap_size, #{size => 20000000, kill => true, error_logger => false}}]),
    receive
        {'DOWN', Ref, process, Pid, {result, R}} -> R;
        {'DOWN', Ref, process, Pid, Other} -> {died, Other}
    after 20000 ->
        exit(Pid, kill),
        timeout
    end.

too_many({'EXIT', {{too_many_cells, Message}, _}}) -> io_lib:printable_unicode_list(Message);
too_many(_) -> false.

%% Along x through cells of 0.1 m (radius 0.05, on a cell border in y and
%% z): each piece of 0.1 m lists 3 x 2 x 2 cells, so 546 m list 65,532 and
%% 547 m 65,652, just past the cap.
cap_along_an_axis_test() ->
    ?assertEqual(65536, rw_hash:max_swept_cells()),
    Under = rw_hash:swept_cells(?ORIGIN, {546.0, 0.0, 0.0}, 0.05, 0.1),
    ?assertEqual(Under, lists:usort(Under)),
    ?assertEqual(21848, length(Under)),
    ?assert(too_many(catch rw_hash:swept_cells(?ORIGIN, {547.0, 0.0, 0.0}, 0.05, 0.1))).

%% 1e5 m in a substep (a sphere at 1e8 m/s) and a radius of 1e-100 moving
%% a millimetre: refused before a piece is listed, within a bounded heap.
refused_without_listing_test_() ->
    {timeout, 60,
     fun() ->
             ?assert(too_many(bounded(fun() -> rw_hash:swept_cells(?ORIGIN, {1.0e5, 0.0, 0.0}, 0.1, 0.2) end))),
             ?assert(too_many(bounded(fun() -> rw_hash:swept_cells({1.0, 2.0, 3.0}, {1.0e5, -1.0e5, 1.0e5}, 0.1, 0.5)
                                      end))),
             ?assert(too_many(bounded(fun() -> rw_hash:swept_cells(?ORIGIN, {1.0e-3, 0.0, 0.0}, 1.0e-100, 5.0e-100)
                                      end)))
     end}.

%% Moves that sweep_bound/4 puts just under the cap, in random directions,
%% sizes and places (near the origin and around 1e9 m, cells of one to
%% twenty radii): none is refused, and the cells listed are within the
%% bound.
bound_lets_through_only_what_the_cap_takes_test_() ->
    {timeout, 120,
     fun() ->
             Cap = rw_hash:max_swept_cells(),
             S0 = rand:seed_s(exsss, 42),
             lists:foldl(
               fun(_, S1) ->
                       {[U1, U2, U3, U4, U5, U6, U7], S2} = uniforms(7, S1),
                       Dir = normalise({U1 - 0.5, U2 - 0.5, U3 - 0.5}),
                       R = 0.01 + U4,
                       S = R * (1.0 + 19.0 * U5),
                       Far = case U6 < 0.5 of true -> 10.0 * U6; false -> 1.0e9 * U6 end,
                       P = {Far, -Far * U7, Far * U7},
                       %% the largest move along an axis whose bound is 0.95 x the cap
                       Move = largest_move(R, S, Far, 0.95 * Cap),
                       Largest = max(abs(element(1, Dir)), max(abs(element(2, Dir)), abs(element(3, Dir)))),
                       D = scale(Dir, Move / Largest),
                       Cells = rw_hash:swept_cells(P, D, R, S),
                       ?assert(length(Cells) =< rw_hash:sweep_bound(Move, R, S, Far)),
                       S2
               end, S0, lists:seq(1, 60)),
             ok
     end}.

%% The move (along an axis) whose bound is Target, by bisection.
largest_move(R, S, Far, Target) -> bisect(R, S, Far, Target, 0.0, 1.0e7, 60).

bisect(_R, _S, _Far, _Target, Lo, _Hi, 0) -> Lo;
bisect(R, S, Far, Target, Lo, Hi, N) ->
    Mid = (Lo + Hi) / 2,
    case rw_hash:sweep_bound(Mid, R, S, Far) =< Target of
        true -> bisect(R, S, Far, Target, Mid, Hi, N - 1);
        false -> bisect(R, S, Far, Target, Lo, Mid, N - 1)
    end.

uniforms(0, S) -> {[], S};
uniforms(N, S0) ->
    {U, S1} = rand:uniform_s(S0),
    {Us, S2} = uniforms(N - 1, S1),
    {[U | Us], S2}.

normalise({X, Y, Z}) ->
    L = math:sqrt(X * X + Y * Y + Z * Z),
    {X / L, Y / L, Z / L}.

scale({X, Y, Z}, F) -> {X * F, Y * F, Z * F}.
