%% The frame ring across a restart: frames at and after the restart point
%% leave the ring, so that the restarted simulation, writing its frames
%% again from there, only ever pushes older frames (and their records) out.
-module(rw_ring_tests).
-include_lib("eunit/include/eunit.hrl").

%% A ring of Size over a records table, with frames at Ticks (ms = ticks),
%% each with one body's record.
ring(Size, Ticks) ->
    Ring = ets:new(ring, [set, public]),
    Records = ets:new(records, [ordered_set, public]),
    ok = rw_ring:init(Ring, Records, 1),
    [begin
         commit(Records, T),
         write(Ring, Records, T, Size)
     end || T <- Ticks],
    {Ring, Records}.

%% As the GVT process writes a frame: the records of the frame that left
%% go.
write(Ring, Records, T, Size) ->
    case rw_ring:write(Ring, T, T, Size) of
        ok -> ok;
        {left, Old} -> rw_commits:delete_at(Old, Records)
    end.

%% The frames a ring keeps: all that are asked for while they hold at most
%% 2^15 body records, else fewer, but not fewer than 4 for that.
frames_kept_test() ->
    ?assertEqual(1024, rw_ring:frames_kept(1024, 1)),
    ?assertEqual(1024, rw_ring:frames_kept(1024, 0)),
    ?assertEqual(1024, rw_ring:frames_kept(1024, 32)),
    ?assertEqual(992, rw_ring:frames_kept(1024, 33)),
    ?assertEqual(20, rw_ring:frames_kept(20, 500)),
    ?assertEqual(65, rw_ring:frames_kept(1024, 500)),
    ?assertEqual(16, rw_ring:frames_kept(1024, 2000)),
    ?assertEqual(4, rw_ring:frames_kept(1024, 8192)),
    ?assertEqual(4, rw_ring:frames_kept(1024, 20000)),
    ?assertEqual(2, rw_ring:frames_kept(2, 500)),
    ?assertEqual(3, rw_ring:frames_kept(3, 100000)).

commit(Records, T) ->
    true = ets:insert(Records, rw_commits:record(T, 0, <<"a">>, {float(T), 0.0, 0.0}, {0.0, 0.0, 0.0}, undefined,
                                                 undefined, {{0.0, 0.0, 0.0}, undefined})).

restart_keeps_recommitted_records_test() ->
    {Ring, Records} = ring(1, [0, 10, 20, 30]),
    %% a restart from the checkpoint at 10: the restarted bodies commit 10,
    %% 20 and 30 again before GVT writes 10 into the ring
    ok = rw_ring:truncate(Ring, 10),
    ok = rw_commits:keep_only(Records, rw_ring:ticks(Ring)),
    [commit(Records, T) || T <- [10, 20, 30]],
    [begin ok = write(Ring, Records, T, 1), ?assertMatch({frame, T, [_]}, rw_ring:frame_at(Ring, T)) end
     || T <- [10, 20, 30]],
    ?assertMatch({frame, 30, [_]}, rw_ring:latest(Ring)),
    ?assertEqual([{30, 0}], [K || {K, _, _} <- ets:tab2list(Records)]).

truncate_keeps_older_frames_in_order_test() ->
    {Ring, Records} = ring(3, [0, 10, 20, 30, 40]),
    ?assertEqual([20, 30, 40], lists:sort(rw_ring:ticks(Ring))),
    ok = rw_ring:truncate(Ring, 35),
    ok = rw_commits:keep_only(Records, rw_ring:ticks(Ring)),
    ?assertMatch({frame, 30, _}, rw_ring:latest(Ring)),
    [commit(Records, T) || T <- [40, 50]],
    ok = write(Ring, Records, 40, 3),
    ok = write(Ring, Records, 50, 3),
    %% the oldest (20) went, in slot order
    ?assertEqual([30, 40, 50], lists:sort(rw_ring:ticks(Ring))),
    ?assertEqual([30, 40, 50], [T || {{T, 0}, _, _} <- ets:tab2list(Records)]),
    ?assertEqual([{frame, T, [B]} || T <- [40, 50], [R] <- [ets:lookup(Records, {T, 0})], {B, _} <- [rw_commits:unpack(R)]],
                 rw_ring:frames_after(Ring, 30, 10)).

truncate_to_nothing_test() ->
    {Ring, _Records} = ring(4, [0, 10]),
    ok = rw_ring:truncate(Ring, 0),
    ?assertEqual(none, rw_ring:latest(Ring)),
    ?assertEqual([], rw_ring:ticks(Ring)).
