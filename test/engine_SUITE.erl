%% The central test: committed frames of the Time Warp engine equal the
%% sequential reference engine bit for bit, for every scenario and for
%% random scenes, whatever the schedulers, stride, bucket count or message
%% timing. Also liveness (random delays, watchdog) and leaks.
-module(engine_SUITE).
-include_lib("proper/include/proper.hrl").
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").
-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([scenarios_equal/1, strides_and_buckets_equal/1, random_scenes_equal/1,
         random_delays_terminate_and_equal/1, watchdog_names_stuck_body/1,
         no_leaks_after_100_runs/1, escript_frames_identical/1, frames_api/1, frame_times_only/1, ring_keeps_last_frames/1,
         contact_groups/1]).

suite() -> [{timetrap, {minutes, 15}}].

all() -> [{group, equality}, {group, liveness}, {group, lifecycle}].

groups() ->
    [{equality, [], [scenarios_equal, strides_and_buckets_equal, random_scenes_equal,
                     escript_frames_identical, contact_groups]},
     {liveness, [], [random_delays_terminate_and_equal, watchdog_names_stuck_body]},
     {lifecycle, [], [no_leaks_after_100_runs, frames_api, frame_times_only, ring_keeps_last_frames]}].

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    Config.

end_per_suite(_Config) -> ok.

%%% Helpers

%% Frames of one run, in order.
frames(Engine, SceneOrFile, Opts) ->
    Self = self(),
    Ref = make_ref(),
    Sink = fun(F) -> Self ! {Ref, F} end,
    {ok, Summary} = case SceneOrFile of
                        File when is_list(File) ->
                            rigidwarp:run(File, Opts#{engine => Engine, on_frame => Sink});
                        Scene ->
                            Run = case Engine of
                                      reference -> rw_reference:run(Scene, #{on_frame => Sink});
                                      timewarp -> rw_timewarp:run(Scene, Opts#{on_frame => Sink})
                                  end,
                            Run
                    end,
    {drain(Ref), Summary}.

drain(Ref) ->
    receive {Ref, F} -> [F | drain(Ref)] after 0 -> [] end.

with_schedulers(N, Fun) ->
    Old = erlang:system_flag(schedulers_online, min(N, erlang:system_info(schedulers))),
    try Fun() after erlang:system_flag(schedulers_online, Old) end.

assert_same(Name, Expected, Actual) ->
    case rw_test_lib:bitwise_equal(Expected, Actual) of
        true -> ok;
        false ->
            Diff = first_diff(Expected, Actual),
            ct:pal("~s differs from the reference; first difference:~n~p", [Name, Diff]),
            ct:fail({not_equal, Name})
    end.

first_diff(A, Failure) when not is_list(Failure) -> {expected, length(A), frames, got, Failure};
first_diff([X | A], [Y | B]) ->
    case rw_test_lib:bitwise_equal(X, Y) of
        true -> first_diff(A, B);
        false -> {expected, X, got, Y}
    end;
first_diff(A, B) -> {length, length(A), length(B)}.

scenario_files() ->
    lists:sort(filelib:wildcard(filename:join([rw_test_lib:root(), "scenarios", "*.json"]))).

%% Long scenes are compared over their first part to keep the suite fast.
until(File) ->
    {ok, Scene} = rigidwarp:load(File, #{}),
    %% (the bundled scenes have 1 ms ticks: their ticks are ms)
    #scene{spheres = Spheres, duration = Duration, substep = Substep, tick_us = 1000} = Scene,
    Bodies = length(Spheres),
    Budget = if Bodies > 300 -> 200; Bodies > 100 -> 400; Bodies > 10 -> 1000; true -> Duration end,
    max(Substep, (min(Duration, Budget) div Substep) * Substep).

%%% Equality

scenarios_equal(_Config) ->
    Files = scenario_files(),
    ?assert(length(Files) > 0),
    Compared = [begin
                    Opts = #{until => until(F)},
                    {Ref, _} = frames(reference, F, Opts),
                    [begin
                         {Tw, #{efficiency := Eff}} = with_schedulers(S, fun() -> frames(timewarp, F, Opts) end),
                         assert_same(io_lib:format("~s on ~b schedulers", [filename:basename(F), S]), Ref, Tw),
                         ct:pal("~s: ~b frames equal on ~b scheduler(s), efficiency ~.3f",
                                [filename:basename(F), length(Ref), S, Eff])
                     end || S <- [1, 2]],
                    F
                end || F <- Files],
    {comment, io_lib:format("~b scenarios x 2 scheduler counts", [length(Compared)])}.

%% One colliding scene over the matrix of strides and bucket counts.
strides_and_buckets_equal(_Config) ->
    File = rw_test_lib:scenario("bouncing_200_100.json"),
    Base = #{until => 300},
    {Ref, _} = frames(reference, File, Base),
    Configs = [{Stride, Buckets, S} || Stride <- [1, 16, 64, 256], Buckets <- [1, 7, 64], S <- [1, 2],
                                       not (Stride =:= 1 andalso Buckets =:= 1)],
    [begin
         {Tw, _} = with_schedulers(S, fun() -> frames(timewarp, File, Base#{stride => Stride, buckets => Buckets}) end),
         assert_same(io_lib:format("stride ~b, ~b buckets, ~b schedulers", [Stride, Buckets, S]), Ref, Tw)
     end || {Stride, Buckets, S} <- Configs],
    {comment, io_lib:format("~b configurations", [length(Configs)])}.

random_scenes_equal(_Config) ->
    Prop = ?FORALL({SceneMap, Stride, Buckets, Sched, Groups}, {scene_map(), stride(), buckets(), oneof([1, 2]), group_options()},
                   case rw_scene:from_map(SceneMap#{<<"stride_ms">> => Stride * maps:get(<<"substep_ms">>, SceneMap)}, #{}) of
                       {error, _} ->
                           true;   % the generator can ask for a packing that cannot be placed
                       {ok, Scene} ->
                           same_as_reference(Scene, Sched, Groups#{buckets => Buckets},
                                             io_lib:format("scene ~p~nstride ~p, ~p buckets, ~p schedulers, ~p",
                                                           [SceneMap, Stride, Buckets, Sched, Groups]))
                   end),
    true = proper:quickcheck(Prop, [{numtests, 100}, {to_file, user}, long_result]).

%% A property: the Time Warp frames of Scene equal the reference's; on
%% failure print What and the first difference (or the exception).
%% PropEr prints how many runs regrouped (contact groups changed).
same_as_reference(Scene, Sched, Opts, What) ->
    {Ref, _} = frames(reference, Scene, #{}),
    {Tw, Regrouped} = try with_schedulers(Sched, fun() -> frames(timewarp, Scene, Opts) end) of
                          {Frames, #{regroups := 0}} -> {Frames, no_regroups};
                          {Frames, #{regroups := _}} -> {Frames, regrouped}
                      catch C:E -> {{C, E}, crashed}
                      end,
    collect(Regrouped, ?WHENFAIL(ct:pal("~s~nfirst diff ~p", [What, first_diff(Ref, Tw)]), rw_test_lib:bitwise_equal(Ref, Tw))).

stride() -> oneof([1, 2, 8, 64, 256]).
buckets() -> oneof([1, 3, 16, 64]).

%% Contact groups: off (one entity per body, as the paper), the default, or
%% small groups of bodies near each other (eager: however they move) that
%% regroup at every stride or every other one.
group_options() ->
    oneof([#{groups => false}, #{},
           #{group_max => 2, regroup_every => 1, grouping => eager},
           #{group_max => 3, regroup_every => 2, grouping => eager},
           #{group_max => 64, regroup_every => 1, grouping => eager}]).

%% Random small scenes: spheres with random velocities in a container,
%% with or without gravity, rotation, friction, CCD, any integrator, at
%% substeps of 0.5 ms (ticks of 0.5 ms), 1 and 2 ms.
scene_map() ->
    ?LET({N, Seed, R, Speed, Half, Restitution, Gravity, Rotation, Friction, Ccd, Integrator, Substep, Dur},
         {range(2, 14), range(1, 1000000), oneof([0.1, 0.2, 0.3]), oneof([0.5, 3.0, 10.0]),
          oneof([1.0, 1.5, 2.5]), oneof([0.0, 0.5, 1.0]), boolean(), boolean(),
          oneof([none, 0.2, 0.8]), boolean(), oneof([<<"symplectic_euler">>, <<"verlet">>, <<"explicit_euler">>]),
          oneof([0.5, 1, 2]), oneof([100, 300])},
         begin
             Model0 = #{<<"restitution">> => Restitution, <<"rotation">> => Rotation, <<"ccd">> => Ccd,
                        <<"integrator">> => Integrator},
             Model1 = case Gravity of true -> Model0#{<<"gravity">> => [0.0, -9.81, 0.0]}; false -> Model0 end,
             Model = case Friction of none -> Model1; Mu -> Model1#{<<"friction">> => Mu} end,
             #{<<"name">> => <<"random">>, <<"duration_ms">> => Dur, <<"substep_ms">> => Substep,
               <<"frame_ms">> => 10 * Substep, <<"model">> => Model,
               <<"bodies">> => [#{<<"id">> => <<"cage">>, <<"shape">> => <<"box">>, <<"static">> => true,
                                  <<"hollow">> => true, <<"half_extents">> => [Half, Half, Half],
                                  <<"position">> => [0, 0, 0]}],
               <<"generators">> => [#{<<"type">> => <<"random">>, <<"id_prefix">> => <<"s">>, <<"count">> => N,
                                      <<"seed">> => Seed, <<"min">> => [-Half, -Half, -Half],
                                      <<"max">> => [Half, Half, Half], <<"radius">> => R, <<"mass">> => 1.0,
                                      <<"speed">> => Speed}]}
         end).

%% The escript writes byte-identical frames files with either engine.
escript_frames_identical(Config) ->
    Dir = ?config(priv_dir, Config),
    File = rw_test_lib:scenario("bouncing_200_250.json"),
    Out = fun(Name, Args) ->
                  Path = filename:join(Dir, Name),
                  {0, Stdout, _} = rw_test_lib:run_escript(["run", File, "--until", "300", "--quiet",
                                                            "--frames", Path | Args]),
                  Summary = jiffy:decode(lists:last(binary:split(string:trim(Stdout), <<"\n">>, [global])),
                                         [return_maps]),
                  {ok, Bin} = file:read_file(Path),
                  {Bin, Summary}
          end,
    {Ref, #{<<"engine">> := <<"reference">>}} = Out("ref.jsonl", ["--engine", "reference"]),
    [begin
         {Bin, #{<<"engine">> := <<"timewarp">>, <<"efficiency">> := Eff, <<"rollbacks">> := Rb}} =
             Out("tw.jsonl", ["--schedulers", S, "--stride", St]),
         ?assert(Eff > 0.0 andalso Eff =< 1.0),
         ?assert(is_integer(Rb)),
         ?assertEqual(Ref, Bin)
     end || S <- ["1", "2"], St <- ["1", "64"]],
    ok.

%% Bodies in persistent contact (Cylinders, once the spheres pile up on
%% the cylinders) are stepped as groups: groups form, the frames equal the
%% reference's whatever their size, and their contacts no longer cost an
%% event each.
contact_groups(_Config) ->
    File = rw_test_lib:scenario("cylinders_200.json"),
    {ok, Scene} = rigidwarp:load(File, #{until => 1000}),
    {Ref, _} = frames(reference, Scene, #{}),
    {Alone, #{events := EventsAlone, regroups := 0}} = frames(timewarp, Scene, #{groups => false}),
    assert_same("one entity per body", Ref, Alone),
    Runs = [{Opts, with_schedulers(S, fun() -> frames(timewarp, Scene, Opts) end)}
            || {Opts, S} <- [{#{}, 2}, {#{group_max => 2}, 1}, {#{group_max => 5, regroup_every => 1}, 2}]],
    [begin
         assert_same(io_lib:format("groups ~p", [Opts]), Ref, Frames),
         ct:pal("~p: ~b regroups, ~b events (one entity per body: ~b)", [Opts, Regroups, Events, EventsAlone]),
         ?assert(Regroups > 0)
     end || {Opts, {Frames, #{regroups := Regroups, events := Events}}} <- Runs],
    [{_, {_, #{events := EventsDefault}}} | _] = Runs,
    ?assert(EventsDefault * 2 < EventsAlone),
    ok.

%%% Liveness

%% Random pauses before every TVHT operation and every message shuffle how
%% bodies interleave: runs must still end, with the same frames.
random_delays_terminate_and_equal(_Config) ->
    %% groups change every stride or two, so that handovers meet the delays
    Prop = ?FORALL({SceneMap, Stride, Seed, MaxMs, Groups},
                   {scene_map(), oneof([1, 2, 8]), range(1, 100000), range(0, 2),
                    oneof([#{groups => false}, #{group_max => 2, regroup_every => 1, grouping => eager},
                           #{group_max => 4, regroup_every => 2, grouping => eager}])},
                   case rw_scene:from_map(SceneMap#{<<"stride_ms">> => Stride * maps:get(<<"substep_ms">>, SceneMap),
                                                    <<"duration_ms">> => 120 * maps:get(<<"substep_ms">>, SceneMap)}, #{}) of
                       {error, _} -> true;
                       {ok, Scene} ->
                           same_as_reference(Scene, 2, Groups#{delay => {Seed, MaxMs}, buckets => 4},
                                             io_lib:format("scene ~p~nstride ~p, delay seed ~p up to ~p ms, ~p",
                                                           [SceneMap, Stride, Seed, MaxMs, Groups]))
                   end),
    true = proper:quickcheck(Prop, [{numtests, 40}, {to_file, user}, long_result]).

watchdog_names_stuck_body(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Scene} = rigidwarp:load(File, #{until => 1000000}),
    {ok, #{sim := _} = H} = rw_timewarp:start(Scene, #{owner => self(), watchdog_ms => 300}),
    #{sim := #sim{procs = Procs}, gvt := Gvt} = H,
    [{_, Body}] = ets:lookup(Procs, 0),
    ok = sys:suspend(Body),
    Report = receive {rw_stalled, Gvt, _G, R} -> R after 5000 -> ct:fail(no_watchdog) end,
    sys:resume(Body),
    rw_timewarp:stop(H),
    %% the suspended body is named first, as the one holding GVT back
    [_Header, First | _] = string:split(Report, "\n", all),
    ?assertMatch({match, _}, re:run(First, "^body a \\(idx 0\\): step at LVT [0-9]+ .*[1-9][0-9]* unread messages")),
    ok.

%%% Lifecycle

no_leaks_after_100_runs(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Scene} = rigidwarp:load(File, #{until => 20}),
    Warm = fun() -> {ok, _} = rw_timewarp:run(Scene, #{buckets => 8}) end,
    Warm(),
    Procs0 = erlang:system_info(process_count),
    Tabs0 = length(ets:all()),
    [Warm() || _ <- lists:seq(1, 100)],
    timer:sleep(100),
    ?assertEqual([], supervisor:which_children(rw_sims_sup)),
    ?assertEqual(Procs0, erlang:system_info(process_count)),
    ?assertEqual(Tabs0, length(ets:all())),
    ok.

frames_api(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Sim} = rigidwarp:start(File, #{}),
    ok = rigidwarp:subscribe(Sim),
    First = receive {rw_frame, _, {frame, 0, _} = F0} -> F0 after 5000 -> ct:fail(no_frame) end,
    ok = rigidwarp:await(Sim, 10000),
    {frame, 1000, Bodies} = rigidwarp:frames(Sim, latest),
    ?assertEqual(2, length(Bodies)),
    ?assertEqual(First, rigidwarp:frames(Sim, 0)),
    ok = rigidwarp:stop(Sim),
    %% sub-millisecond frames are read by their time in ms, 20 and 20.0 alike
    {ok, Fine} = rigidwarp:start(File, #{substep => 0.25, frame_ms => 0.5, until => 20}),
    ok = rigidwarp:await(Fine, 10000),
    ?assertEqual(20, rigidwarp:gvt(Fine)),
    ?assertMatch({frame, 20, _}, rigidwarp:frames(Fine, latest)),
    ?assertMatch({frame, 0.5, _}, rigidwarp:frames(Fine, 0.5)),
    ?assertMatch({frame, 20, _}, rigidwarp:frames(Fine, 20.0)),
    ?assertEqual(none, rigidwarp:frames(Fine, 0.25)),
    ?assertMatch([{frame, 19, _}, {frame, 19.5, _}, {frame, 20, _}], rigidwarp:frames_after(Fine, 18.5, 5)),
    ?assertMatch(#{gvt := 20, end_ms := 20, max_lvt := 20}, rigidwarp:stats(Fine)),
    ok = rigidwarp:stop(Fine),
    ok.

%% Without on_frame the frames stay in the engine: the runner hears only
%% their times (for on_progress and the count), in order, one per frame.
frame_times_only(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Scene} = rigidwarp:load(File, #{until => 200}),
    {Frames, #{frames := N}} = frames(timewarp, Scene, #{}),
    ?assertEqual(length(Frames), N),
    Self = self(),
    {ok, #{frames := N}} = rw_timewarp:run(Scene, #{on_progress => fun(#{gvt := G}) -> Self ! {progress, G} end}),
    Times = [T || {frame, T, _} <- Frames],
    ?assertEqual(Times, receive_all(progress)),
    {ok, H} = rw_timewarp:start(Scene, #{owner => self(), subscribe => times}),
    #{gvt := Gvt} = H,
    receive {rw_done, Gvt, 200} -> ok after 10000 -> ct:fail(not_done) end,
    rw_timewarp:stop(H),
    ?assertEqual(Times, receive_all(rw_frame_time)),
    ?assertEqual([], receive_all(rw_frame)),
    ok.

receive_all(progress) -> receive {progress, G} -> [G | receive_all(progress)] after 0 -> [] end;
receive_all(rw_frame_time) -> receive {rw_frame_time, _, T} -> [T | receive_all(rw_frame_time)] after 0 -> [] end;
receive_all(rw_frame) -> receive {rw_frame, _, F} -> [F | receive_all(rw_frame)] after 0 -> [] end.

%% The ring keeps the last ring_size frames, read from the records the
%% bodies committed; the records of older frames are gone (a long run does
%% not keep its history).
ring_keeps_last_frames(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Scene} = rigidwarp:load(File, #{until => 200}),
    {Frames, _} = frames(timewarp, Scene, #{}),
    {ok, #{sim := #sim{records = Records, n = N}} = H} = rw_timewarp:start(Scene, #{owner => self(), ring_size => 4}),
    #{gvt := Gvt, ring := Ring} = H,
    receive {rw_done, Gvt, 200} -> ok after 10000 -> ct:fail(not_done) end,
    Last4 = lists:nthtail(length(Frames) - 4, Frames),
    ?assertEqual(Last4, rw_ring:frames_after(Ring, -1, 10)),
    ?assertEqual(lists:last(Frames), rw_ring:latest(Ring)),
    {frame, Evicted, _} = lists:nth(length(Frames) - 4, Frames),
    ?assertEqual(none, rw_ring:frame_at(Ring, Evicted)),
    ?assertEqual(4 * N, ets:info(Records, size)),
    rw_timewarp:stop(H),
    ok.
