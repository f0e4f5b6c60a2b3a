%% The sync calendar: frame times, stride multiples, regroup points and the
%% end, and where GVT stops next.
-module(rw_sync_tests).
-include_lib("eunit/include/eunit.hrl").

%% frames every 10, stride 64, regroup every 20, end at 150
cal() -> rw_sync:new(10, 64, 150, 20).

sync_points_test() ->
    C = cal(),
    ?assertEqual([0, 10, 20, 30, 40, 50, 60, 64, 70, 80, 90, 100, 110, 120, 128, 130, 140, 150],
                 [T || T <- lists:seq(0, 150), rw_sync:is_sync(T, C)]),
    ?assertEqual([0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110, 120, 130, 140, 150],
                 [T || T <- lists:seq(0, 150), rw_sync:is_frame(T, C)]).

after_gvt_test() ->
    C = cal(),
    ?assertEqual(0, rw_sync:after_gvt(-1, C)),
    ?assertEqual(10, rw_sync:after_gvt(0, C)),
    ?assertEqual(64, rw_sync:after_gvt(60, C)),
    ?assertEqual(70, rw_sync:after_gvt(64, C)),
    ?assertEqual(150, rw_sync:after_gvt(140, C)),
    %% every sync point is the next one after the one before it
    Points = [T || T <- lists:seq(0, 150), rw_sync:is_sync(T, C)],
    ?assertEqual(tl(Points), [rw_sync:after_gvt(T, C) || T <- lists:droplast(Points)]).

last_before_test() ->
    C = cal(),
    ?assertEqual(0, rw_sync:last_before(9, C)),
    ?assertEqual(64, rw_sync:last_before(69, C)),
    ?assertEqual(60, rw_sync:last_before(63, C)).

%% Without contact groups there are no regroup points of their own.
no_groups_test() ->
    C = rw_sync:new(10, 16, 100, 0),
    ?assertEqual(16, rw_sync:after_gvt(10, C)),
    ?assertNot(rw_sync:is_sync(25, C)).

%% The next sync point at or after each time is the first time from there
%% at which is_sync/2 holds, with and without regroup points; none past the
%% end.
next_at_test() ->
    [?assertEqual(hd([S || S <- lists:seq(T, 150), rw_sync:is_sync(S, C)]), rw_sync:next_at(T, C))
     || C <- [cal(), rw_sync:new(10, 16, 100, 0), rw_sync:new(7, 64, 150, 0)], T <- lists:seq(0, rw_sync:end_t(C))],
    ?assertEqual(none, rw_sync:next_at(151, cal())).
