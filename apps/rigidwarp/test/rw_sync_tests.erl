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

%% Only every third frame time a sync point (nobody reads the frames):
%% the other frames are still frames, passed with the next sync point.
sparse_test() ->
    C = rw_sync:sparse(rw_sync:new(10, 64, 150, 30), 3),
    ?assertEqual([0, 30, 60, 64, 90, 120, 128, 150], [T || T <- lists:seq(0, 150), rw_sync:is_sync(T, C)]),
    ?assertEqual([T || T <- lists:seq(0, 150), rw_sync:is_frame(T, cal())],
                 [T || T <- lists:seq(0, 150), rw_sync:is_frame(T, C)]),
    ?assertEqual([10, 20], rw_sync:frames_before(30, C)),
    ?assertEqual([], rw_sync:frames_before(64, C)),
    ?assertEqual([70, 80], rw_sync:frames_before(90, C)),
    ?assertEqual([130, 140], rw_sync:frames_before(150, C)),
    ?assertEqual([], rw_sync:frames_before(0, C)),
    ?assertEqual([], rw_sync:frames_before(30, cal())),
    ?assertEqual(90, rw_sync:sync_frame_after(64, C)),
    ?assertEqual(90, rw_sync:sync_frame_after(60, C)),
    ?assertEqual(20, rw_sync:sync_frame_after(10, cal())).

%% For calendars with and without sparse frames, from 0 and from a later
%% start that is no multiple of the sync frames (a run resumed from any
%% frame): the start is a sync point; next_at/2 and last_before/2 find the
%% sync points that is_sync/2 names; and every frame time after the start
%% is a sync point or is passed with one (frames_before/2), once.
sparse_calendars_test() ->
    [begin
         End = rw_sync:end_t(C),
         Syncs = [T || T <- lists:seq(Start, End), rw_sync:is_sync(T, C)],
         ?assertEqual(Start, hd(Syncs)),
         [?assertEqual(hd([S || S <- Syncs, S >= T]), rw_sync:next_at(T, C)) || T <- lists:seq(Start, End)],
         [?assertEqual(lists:last([S || S <- Syncs, S =< T]), rw_sync:last_before(T, C))
          || T <- lists:seq(Start, End - 1)],
         Frames = [T || T <- lists:seq(Start + 1, End), rw_sync:is_frame(T, C)],
         Passed = lists:append([rw_sync:frames_before(T, C) ++ [T || rw_sync:is_frame(T, C)] || T <- tl(Syncs)]),
         ?assertEqual(Frames, Passed),
         [?assertEqual(hd([S || S <- Syncs, S > T, S rem 10 =:= 0, S < End]), rw_sync:sync_frame_after(T, C))
          || T <- lists:seq(Start, End - 100)]
     end || Start <- [0, 20, 70], Every <- [1, 2, 3, 7], Period <- [0, 30],
            C <- [rw_sync:sparse(rw_sync:new(10, 64, 300, Period * Every, Start), Every)]].
