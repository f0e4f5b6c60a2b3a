%% Backpressure (rw_flow): a run goes no further ahead of its subscribers
%% than a window of frames. A slow on_frame holds GVT instead of letting
%% frames pile up in its mailbox; a shell subscriber that does not read
%% holds it until it reads, through restarts and without the watchdog
%% taking it for a stall; one waiting for the end in await/2 holds
%% nothing. The frames stay the reference's bit for bit.
-module(flow_SUITE).
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").
-include("rw_test.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([slow_on_frame_holds_gvt/1, unread_subscriber_holds_gvt/1, unread_times_hold_gvt/1,
         held_through_a_restart/1, awaiting_subscriber_holds_nothing/1]).

suite() -> [{timetrap, {minutes, 3}}].

all() -> [slow_on_frame_holds_gvt, unread_subscriber_holds_gvt, unread_times_hold_gvt, held_through_a_restart,
          awaiting_subscriber_holds_nothing].

%% Bouncing 50: spheres in a box, contacts all along; its 3 s run
%% (300 frames) takes a few tenths of a second on two cores.
-define(UNTIL, 3000).
-define(BODIES, 50).

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    logger:set_application_level(rigidwarp, error),
    [{"bouncing_50_250", Scene}] = rw_test_lib:scenes_with_reference([{"bouncing_50_250", scenario, ?UNTIL}]),
    [{scene, Scene} | Config].

end_per_suite(_Config) ->
    logger:unset_application_level(rigidwarp),
    ok.

%% The most frames a subscriber may hold unread: the window, and a frame
%% delivered as the allowance moves.
most_unread() -> rw_flow:window(?BODIES, frames) + 2.

%% on_frame sleeps 10 ms on each of the first 150 frames (the run alone
%% would be over long before): the frames waiting in run/2's mailbox never
%% exceed the window, and the frames are the reference's.
slow_on_frame_holds_gvt(Config) ->
    {Scene, Reference} = ?config(scene, Config),
    OnFrame = fun({frame, T, _} = F) ->
                      put(frames, [F | get(frames)]),
                      case T < ?UNTIL div 2 of
                          true ->
                              timer:sleep(10),
                              {message_queue_len, Unread} = process_info(self(), message_queue_len),
                              put(most_unread, max(Unread, get(most_unread)));
                          false -> ok
                      end
              end,
    put(frames, []),
    put(most_unread, 0),
    {ok, #{frames := N}} = rw_timewarp:run(Scene, #{on_frame => OnFrame}),
    ct:log("at most ~b frames unread (window ~b)", [get(most_unread), rw_flow:window(?BODIES, frames)]),
    ?assert(get(most_unread) =< most_unread()),
    ?assertEqual(length(Reference), N),
    ?assertBitwise(Reference, lists:reverse(get(frames))),
    ok.

%% A shell subscriber that does not read: GVT stops within a window of the
%% frames it has, stays there, and goes on as it reads; the frames it gets
%% are the reference's.
unread_subscriber_holds_gvt(Config) ->
    {Scene, Reference} = ?config(scene, Config),
    {ok, Sim} = rigidwarp:start(Scene#scene.file, #{until => ?UNTIL}),
    ok = rigidwarp:subscribe(Sim),
    Held = held_gvt(Sim),
    ?assert(Held < ?UNTIL),
    ?assert(unread() =< most_unread()),
    Frames = read_until(?UNTIL),
    ?assertMatch(#{gvt := ?UNTIL}, rigidwarp:stats(Sim)),
    ?assertBitwise(lists:nthtail(length(Reference) - length(Frames), Reference), Frames),
    ok = rigidwarp:stop(Sim).

%% The same for the times of frames (rw_timewarp:start/2's owner
%% subscribed to times): small messages, but as many.
unread_times_hold_gvt(Config) ->
    {Scene, _} = ?config(scene, Config),
    {ok, {rw_sim, Run, _} = H} = rw_timewarp:start(Scene, #{owner => self(), subscribe => times}),
    Held = held_gvt(H),
    ?assert(Held < ?UNTIL),
    ?assert(unread() =< rw_flow:window(?BODIES, times) + 2),
    Times = read_times(Run),
    ?assertEqual([rw_scene:ms(Scene, T) || T <- lists:seq(0, Scene#scene.duration, Scene#scene.frame)], Times),
    ok = rw_timewarp:stop(H).

%% A subscriber that does not read holds GVT through a restart (the new
%% tree keeps to the same allowance), and the watchdog, looking every
%% 75 ms, takes none of it for a stall (no restart is allowed); the frames
%% are the reference's.
held_through_a_restart(Config) ->
    {Scene, Reference} = ?config(scene, Config),
    {ok, {rw_sim, Run, _} = Sim} = rigidwarp:start(Scene#scene.file, #{until => ?UNTIL, watchdog_ms => 300,
                                                                       max_restarts => 1}),
    ok = rigidwarp:subscribe(Sim),
    Held = held_gvt(Sim),
    timer:sleep(600),
    ?assertMatch(#{gvt := Held, status := running, restarts := 0}, rigidwarp:stats(Sim)),
    [Body | _] = [P || {P, {body, _}} <- rw_run:processes(Run)],
    exit(Body, kill),
    timer:sleep(300),
    ?assertMatch(#{gvt := Held, status := running, restarts := 1}, rigidwarp:stats(Sim)),
    Frames = read_until(?UNTIL),
    ?assertBitwise(lists:nthtail(length(Reference) - length(Frames), Reference), Frames),
    ok = rigidwarp:stop(Sim).

%% A subscriber waiting in await/2 reads nothing until the end: the run
%% does not wait for it, and every frame since it subscribed is in its
%% mailbox at the end.
awaiting_subscriber_holds_nothing(Config) ->
    {Scene, Reference} = ?config(scene, Config),
    {ok, Sim} = rigidwarp:start(Scene#scene.file, #{until => ?UNTIL}),
    ok = rigidwarp:subscribe(Sim),
    ok = rigidwarp:await(Sim, 30000),
    Frames = read_until(?UNTIL),
    ?assert(length(Frames) > most_unread()),
    ?assertBitwise(lists:nthtail(length(Reference) - length(Frames), Reference), Frames),
    ok = rigidwarp:stop(Sim).

%% GVT once it has stood still for 200 ms (in ms; the run's GVT, read by
%% its stats).
held_gvt(Sim) -> held_gvt(Sim, gvt_of(Sim), 0).

held_gvt(_Sim, G, Still) when Still >= 200 -> G;
held_gvt(Sim, G, Still) ->
    timer:sleep(20),
    case gvt_of(Sim) of
        G -> held_gvt(Sim, G, Still + 20);
        G1 -> held_gvt(Sim, G1, 0)
    end.

gvt_of({rw_sim, _, _} = H) -> maps:get(gvt, rw_timewarp:stats(H));
gvt_of(Sim) -> maps:get(gvt, rigidwarp:stats(Sim)).

unread() ->
    {message_queue_len, N} = process_info(self(), message_queue_len),
    N.

read_until(End) ->
    receive
        {rw_frame, _, {frame, End, _} = F} -> [F];
        {rw_frame, _, F} -> [F | read_until(End)]
    after 10000 -> ct:fail(no_frame)
    end.

read_times(Run) ->
    receive
        {rw_frame_time, Run, T} -> [T | read_times(Run)];
        {rw_done, Run, _} -> []
    after 10000 -> ct:fail(no_frame_time)
    end.
