%% One simulation over several Erlang nodes: its frames equal the
%% reference's bit for bit on 1, 2 and 3 nodes (contact-heavy scenes and
%% random ones), a node lost mid-run costs nothing, the peer nodes a run
%% starts are gone when it ends, however it ends, and every node runs the
%% engine's C loops where it can load them (and the Erlang code, with the
%% same frames, where it cannot).
%%
%% Most cases run over two peer nodes the suite starts once (a run given
%% node names connects to them and loads the engine there); the cases of
%% node loss and of node lifetime let the run start its own peers.
-module(nodes_SUITE).
-include_lib("proper/include/proper.hrl").
-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").
-include("rw_test.hrl").
-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([peers_run_the_c_loops/1, peer_without_library_equal/1, every_scenario_equal/1, contact_scenes_equal/1, random_scenes_equal/1, piles_regroup_across_batches/1, own_peers_equal_and_stopped/1, node_killed_mid_run/1,
         node_stopped_mid_run/1, lost_node_work_still_counted/1, bodies_move_to_the_node_of_their_space/1, peers_stopped_however_the_run_ends/1, cross_node_traffic_is_counted/1,
         bad_nodes_are_refused/1, watchdog_names_stuck_body_elsewhere/1]).

suite() -> [{timetrap, {minutes, 10}}].

all() -> [peers_run_the_c_loops, peer_without_library_equal, every_scenario_equal, contact_scenes_equal, random_scenes_equal, piles_regroup_across_batches, own_peers_equal_and_stopped, node_killed_mid_run,
          node_stopped_mid_run, lost_node_work_still_counted, bodies_move_to_the_node_of_their_space, peers_stopped_however_the_run_ends, cross_node_traffic_is_counted,
          bad_nodes_are_refused, watchdog_names_stuck_body_elsewhere].

%% Piles, cylinders, a dense gas and obstacles, over parts with contacts
%% all along.
-define(SCENES, [{"pile_40", test, 1200}, {"rain_on_logs", test, 800}, {"cylinders_200", scenario, 1500},
                 {"bouncing_200_400", scenario, 800}]).

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(rigidwarp),
    logger:set_application_level(rigidwarp, error),
    Scenes = rw_test_lib:scenes_with_reference(?SCENES),
    [{scenes, Scenes} | Config].

end_per_suite(_Config) ->
    logger:unset_application_level(rigidwarp),
    ok.

%% Two peers of the suite's own, stopped at the end of the case.
with_peers(Fun) ->
    {ok, #{nodes := [_ | Nodes]} = Started} = rw_nodes:start(3, 1),
    try Fun(Nodes) after rw_nodes:stop(Started) end.

drain(Tag) -> receive {Tag, F} -> [F | drain(Tag)] after 0 -> [] end.

frames(Scene, Opts) ->
    Self = self(),
    Ref = make_ref(),
    Result = rw_timewarp:run(Scene, Opts#{on_frame => fun(F) -> Self ! {Ref, F} end}),
    {Result, drain(Ref)}.

%% The scene of SceneMap at Stride substeps of stride, run with Opts and no
%% restart allowed (no fault is injected: any restart is a bug), has the
%% reference's frames bit for bit; true for a packing that cannot be placed,
%% and for a scene whose reference runs away, which goes into Runaways
%% (rw_test_lib:runaway/3).
equal_to_reference(SceneMap, Stride, Opts, Runaways) ->
    case rw_scene:from_map(SceneMap#{<<"stride_ms">> => Stride * maps:get(<<"substep_ms">>, SceneMap)}, #{}) of
        {error, _} ->
            true;
        {ok, Scene} ->
            case rw_test_lib:bounded_reference(Scene) of
                {ok, {Reference, _}} ->
                    {Result, Frames} = frames(Scene, Opts#{max_restarts => 0, watchdog_ms => 5000}),
                    ?WHENFAIL(ct:pal("scene ~p~nstride ~p, ~p: ~P~nfirst difference ~p",
                                     [SceneMap, Stride, Opts, Result, 8,
                                      rw_test_lib:first_difference(Reference, Frames)]),
                              element(1, Result) =:= ok andalso rw_test_lib:bitwise_equal(Reference, Frames));
                {error, Why} ->
                    rw_test_lib:runaway(Runaways, Why, io_lib:format("scene ~p~nstride ~p", [SceneMap, Stride]))
            end
    end.

%% A property over equal_to_reference/4, then no scene ran away.
quickcheck_equal(Prop, NumTests) ->
    Runaways = ets:new(runaways, [public]),
    true = proper:quickcheck(Prop(Runaways), [{numtests, NumTests}, {to_file, user}, long_result]),
    rw_test_lib:check_runaways(Runaways).

%%% Cases

%% Every bundled scenario, over the part engine_SUITE compares, on 2 and 3
%% nodes.
every_scenario_equal(_Config) ->
    with_peers(
      fun([A, B]) ->
              Files = engine_SUITE:scenario_files(),
              [begin
                   {ok, Scene} = rigidwarp:load(F, #{until => engine_SUITE:until(F)}),
                   Reference = rw_test_lib:reference_frames(Scene),
                   [begin
                        {Result, Frames} = frames(Scene, #{nodes => Nodes}),
                        ?assertMatch({ok, #{restarts := 0}}, Result),
                        ?assertBitwise(Reference, Frames)
                    end || Nodes <- [[A], [A, B]]]
               end || F <- Files],
              {comment, io_lib:format("~b scenarios x 2 and 3 nodes", [length(Files)])}
      end).

%% The nodes a run loads the engine on load its C loops too (rw_native),
%% from a copy that is gone once they have.
peers_run_the_c_loops(_Config) ->
    ?assert(rw_native:loaded()),
    with_peers(
      fun(Peers) ->
              [begin
                   ?assert(erpc:call(Peer, rw_native, loaded, [])),
                   ?assertEqual(false, erpc:call(Peer, os, getenv, [rw_native:library_variable()]))
               end || Peer <- Peers],
              ok
      end).

%% A peer the library cannot be copied to (its TMPDIR does not exist) loads
%% the engine without it and runs the Erlang code for its share of the
%% bodies and buckets, beside this node's C loops: the frames are the
%% reference's, and the summary says the C loops did not run on every node.
peer_without_library_equal(Config) ->
    ?assert(rw_native:loaded()),
    Missing = filename:join(?config(priv_dir, Config), "no_such_dir"),
    Old = os:getenv("TMPDIR"),
    %% (a peer inherits this node's environment)
    true = os:putenv("TMPDIR", Missing),
    Started = try rw_nodes:start(2, 1)
              after
                  case Old of
                      false -> os:unsetenv("TMPDIR");
                      _ -> os:putenv("TMPDIR", Old)
                  end
              end,
    {ok, #{nodes := [_, Peer]} = Nodes} = Started,
    try
        ?assertNot(erpc:call(Peer, rw_native, loaded, [])),
        [begin
             {Result, Frames} = frames(Scene, #{nodes => [Peer]}),
             ?assertMatch({ok, #{restarts := 0, nodes := 2, native := false}}, Result),
             {ok, #{cross_node_messages := Crossing}} = Result,
             ?assert(Crossing > 0),
             ?assertBitwise(Reference, Frames),
             ct:pal("~s: ~b frames equal, C loops here and Erlang on ~s", [Name, length(Frames), Peer])
         end || {Name, {Scene, Reference}} <- ?config(scenes, Config), lists:member(Name, ["pile_40", "cylinders_200"])],
        %% (the run loaded the engine on the peer again, still without it)
        ?assertNot(erpc:call(Peer, rw_native, loaded, [])),
        ok
    after
        rw_nodes:stop(Nodes)
    end.

%% Every contact-heavy scene on 1, 2 and 3 nodes: the reference's frames.
contact_scenes_equal(Config) ->
    with_peers(
      fun([A, B]) ->
              [begin
                   {Result, Frames} = frames(Scene, #{nodes => Nodes}),
                   ?assertMatch({ok, _}, Result),
                   {ok, #{restarts := 0}} = Result,
                   ?assertBitwise(Reference, Frames),
                   ct:pal("~s: ~b frames equal on ~b node(s)", [Name, length(Frames), length(Nodes) + 1])
               end || {Name, {Scene, Reference}} <- ?config(scenes, Config), Nodes <- [[], [A], [A, B]]],
              ok
      end).

%% Random scenes (engine_SUITE's: gases, piles, obstacles, contact groups
%% on or off, any stride and bucket count) on 2 and 3 nodes.
random_scenes_equal(_Config) ->
    with_peers(
      fun([A, B]) ->
              Prop = fun(Runaways) ->
                             ?FORALL({SceneMap, Stride, Buckets, Nodes, Groups},
                                     {engine_SUITE:scene_map(), engine_SUITE:stride(), oneof([2, 4, 16]),
                                      oneof([[A], [A, B]]), engine_SUITE:group_options()},
                                     collect(length(Nodes) + 1,
                                             equal_to_reference(SceneMap, Stride,
                                                                Groups#{buckets => Buckets, nodes => Nodes}, Runaways)))
                     end,
              quickcheck_equal(Prop, 40)
      end).

%% Piles with contact groups planned from the pairs that met: a batch of
%% sync points that GVT confirms may pass a regroup point that was quiet
%% when it was asked for and met pairs since; GVT must stop before the
%% next regroup point once entities are told to stop there. A GVT that
%% passed it would have an entity roll back to a sync point GVT had passed
%% and crash withdrawing its forgotten commit (3 pile runs in 200 did, with
%% no restart allowed; this property catches that within 60).
piles_regroup_across_batches(_Config) ->
    with_peers(
      fun([A, _]) ->
              Prop = fun(Runaways) ->
                             ?FORALL({SceneMap, Stride}, {engine_SUITE:pile(), engine_SUITE:stride()},
                                     equal_to_reference(SceneMap, Stride, #{nodes => [A]}, Runaways))
                     end,
              quickcheck_equal(Prop, 60)
      end).

%% A run that starts its own peer nodes (nodes => N) gives the same frames,
%% and its peers are gone when it returns.
own_peers_equal_and_stopped(Config) ->
    {Scene, Reference} = proplists:get_value("pile_40", ?config(scenes, Config)),
    Before = nodes(),
    {Result, Frames} = frames(Scene, #{nodes => 3, schedulers => 1}),
    ?assertMatch({ok, _}, Result),
    ?assertBitwise(Reference, Frames),
    ?assertEqual([], wait_for_nodes(Before)),
    ok.

%% A peer node killed mid-run (kill -9 of its OS process): the run goes on
%% from its latest checkpoint on the nodes left, and its frames are the
%% reference's.
node_killed_mid_run(Config) ->
    lose_a_node(Config, fun(Node) ->
                                OsPid = erpc:call(Node, os, getpid, []),
                                os:cmd("kill -9 " ++ OsPid)
                        end).

%% The same when a peer node is stopped (peer:stop/1).
node_stopped_mid_run(Config) ->
    lose_a_node(Config, fun(Run, Node) ->
                                #{peers := Peers} = rw_run:nodes(Run),
                                {Node, Peer} = lists:keyfind(Node, 1, Peers),
                                peer:stop(Peer)
                        end).

lose_a_node(Config, Kill) when is_function(Kill, 1) ->
    lose_a_node(Config, fun(_Run, Node) -> Kill(Node) end);
lose_a_node(Config, Kill) ->
    {Scene, Reference} = proplists:get_value("pile_40", ?config(scenes, Config)),
    Self = self(),
    Before = nodes(),
    OnFrame = fun({frame, 400, _} = F) ->
                      [Run] = [P || {_, P, _, _} <- supervisor:which_children(rw_sims_sup)],
                      %% a node with bodies of the pile
                      [Node | _] = [N || {P, {body, _}} <- rw_run:processes(Run), N <- [node(P)], N =/= node()],
                      _ = Kill(Run, Node),
                      Self ! {killed, Node},
                      Self ! {frame, F};
                 (F) -> Self ! {frame, F}
              end,
    %% no migration: one that starts a new tree just as the node dies takes
    %% the loss in its stride, and the run would not restart
    Result = rw_timewarp:run(Scene, #{nodes => 3, schedulers => 1, checkpoint_ms => 50, migrate => false,
                                      on_frame => OnFrame}),
    Frames = drain(frame),
    Killed = receive {killed, N} -> N after 0 -> none end,
    ?assertNotEqual(none, Killed),
    ?assertMatch({ok, #{restarts := R}} when R >= 1, Result),
    ?assertBitwise(Reference, Frames),
    ?assertEqual([], wait_for_nodes(Before)),
    ok.

%% The work of a node lost mid-run still counts: a scene with no contacts
%% (its efficiency is 1 without faults) over three nodes, one killed a
%% third of the way: efficiency stays at or below 1 (the counters of the
%% lost node are those read at the latest checkpoint, from which the run
%% goes on), and the frames are the reference's.
lost_node_work_still_counted(_Config) ->
    {ok, Scene} = rigidwarp:load(rw_test_lib:scenario("parallel_200.json"), #{until => 3000}),
    Reference = rw_test_lib:reference_frames(Scene),
    Before = nodes(),
    Self = self(),
    OnFrame = fun({frame, 1000, _} = F) ->
                      [Run] = [P || {_, P, _, _} <- supervisor:which_children(rw_sims_sup)],
                      [Node | _] = [N || {P, {body, _}} <- rw_run:processes(Run), N <- [node(P)], N =/= node()],
                      OsPid = erpc:call(Node, os, getpid, []),
                      _ = os:cmd("kill -9 " ++ OsPid),
                      Self ! {frame, F};
                 (F) -> Self ! {frame, F}
              end,
    Result = rw_timewarp:run(Scene, #{nodes => 3, schedulers => 1, checkpoint_ms => 10, migrate => false,
                                      on_frame => OnFrame}),
    ?assertMatch({ok, #{restarts := 1}}, Result),
    {ok, #{efficiency := Efficiency, computed_substeps := Computed, committed_substeps := Committed}} = Result,
    ct:log("efficiency ~p: ~b substeps computed, ~b committed", [Efficiency, Computed, Committed]),
    ?assert(Computed >= Committed),
    ?assert(Efficiency =< 1.0),
    ?assertBitwise(Reference, drain(frame)),
    ?assertEqual([], wait_for_nodes(Before)),
    ok.

%% Two columns of spheres pass each other along x, through the cut between
%% the two nodes' slabs, and a few meet at the walls of a box: once a
%% checkpoint finds a tenth of the bodies in the other node's slab, the run
%% places them anew, and the frames stay the reference's.
bodies_move_to_the_node_of_their_space(_Config) ->
    Column = fun(Prefix, X, Vx) ->
                     #{<<"type">> => <<"grid">>, <<"id_prefix">> => Prefix, <<"count">> => [3, 4, 3],
                       <<"origin">> => [X, -3.0, -2.0], <<"spacing">> => [1.5, 1.5, 1.5], <<"radius">> => 0.5,
                       <<"mass">> => 1.0, <<"velocity">> => [Vx, 0.0, 0.0]}
             end,
    Map = #{<<"name">> => <<"crossing">>, <<"duration_ms">> => 1500, <<"substep_ms">> => 1, <<"frame_ms">> => 10,
            <<"stride_ms">> => 32, <<"model">> => #{<<"restitution">> => 0.9},
            <<"bodies">> => [#{<<"id">> => <<"box">>, <<"shape">> => <<"box">>, <<"static">> => true,
                               <<"hollow">> => true, <<"position">> => [0.0, 0.0, 0.0],
                               <<"half_extents">> => [14.0, 6.0, 8.0]}],
            %% the columns' lanes are apart in z: they pass without meeting
            <<"generators">> => [Column(<<"a">>, -10.0, 12.0),
                                 maps:update_with(<<"origin">>, fun([X, Y, _]) -> [X, Y, 3.0] end, Column(<<"b">>, 7.0, -12.0))]},
    {ok, Scene} = rw_scene:from_map(Map, #{}),
    Reference = rw_test_lib:reference_frames(Scene),
    with_peers(
      fun([A, _]) ->
              {Result, Frames} = frames(Scene, #{nodes => [A], checkpoint_ms => 20}),
              ?assertMatch({ok, #{migrations := M, restarts := 0}} when M >= 1, Result),
              ?assertBitwise(Reference, Frames),
              {ok, #{migrations := M}} = Result,
              %% unless told not to
              {Still, StillFrames} = frames(Scene, #{nodes => [A], checkpoint_ms => 20, migrate => false}),
              ?assertMatch({ok, #{migrations := 0}}, Still),
              ?assertBitwise(Reference, StillFrames),
              {comment, io_lib:format("~b migrations", [M])}
      end).

%% The peers of a run go when it is stopped, when it crashes past its
%% budget, and when its process is killed.
peers_stopped_however_the_run_ends(Config) ->
    {Scene, _} = proplists:get_value("pile_40", ?config(scenes, Config)),
    Before = nodes(),
    {ok, Sim} = rigidwarp:start(Scene#scene.file, #{until => 1200, nodes => 2}),
    ?assertMatch([_], nodes() -- Before),
    ok = rigidwarp:stop(Sim),
    ?assertEqual([], wait_for_nodes(Before)),
    {ok, {rw_sim, Run, _} = Sim2} = rigidwarp:start(Scene#scene.file, #{until => 1200, nodes => 2, max_restarts => 0}),
    [Body | _] = [P || {P, {body, _}} <- rw_run:processes(Run), node(P) =/= node()],
    exit(Body, kill),
    ?assertMatch({error, {crashed, _, _}}, rigidwarp:await(Sim2, 10000)),
    ok = rigidwarp:stop(Sim2),
    ?assertEqual([], wait_for_nodes(Before)),
    {ok, {rw_sim, Run3, _}} = rigidwarp:start(Scene#scene.file, #{until => 1200, nodes => 2}),
    exit(Run3, kill),
    ?assertEqual([], wait_for_nodes(Before)),
    ok.

%% stats/1 and the summary count what crossed between nodes.
cross_node_traffic_is_counted(Config) ->
    {Scene, _} = proplists:get_value("pile_40", ?config(scenes, Config)),
    with_peers(
      fun([A, _]) ->
              {ok, One} = rw_timewarp:run(Scene, #{}),
              {ok, Two} = rw_timewarp:run(Scene, #{nodes => [A]}),
              ?assertEqual(1, maps:get(nodes, One)),
              ?assertEqual(2, maps:get(nodes, Two)),
              ?assertNot(maps:is_key(cross_node_messages, One)),
              ?assert(maps:get(cross_node_messages, Two) > 0),
              ?assert(maps:get(cross_node_bytes, Two) > maps:get(cross_node_messages, Two)),
              %% the lead over GVT (the progress line's "GVT lag") is read
              %% from the bodies' own nodes: Parallel's bodies run up to a
              %% stride ahead
              {ok, Parallel} = rigidwarp:load(rw_test_lib:scenario("parallel_200.json"), #{}),
              {ok, H} = rw_timewarp:start(Parallel, #{owner => self(), nodes => [A]}),
              Leads = [begin
                           timer:sleep(20),
                           #{gvt := G, max_lvt := Max} = rw_timewarp:stats(H),
                           Max - G
                       end || _ <- lists:seq(1, 20)],
              rw_timewarp:stop(H),
              ?assert(lists:max(Leads) > 0),
              ok
      end).

%% A body stuck on another node is named by the watchdog, described on its
%% own node.
watchdog_names_stuck_body_elsewhere(_Config) ->
    File = rw_test_lib:scenario("head_on_elastic.json"),
    {ok, Scene} = rigidwarp:load(File, #{until => 1000000}),
    with_peers(
      fun([A, _]) ->
              {ok, {rw_sim, Run, _} = H} = rw_timewarp:start(Scene, #{owner => self(), watchdog_ms => 300,
                                                                      max_restarts => 0, nodes => [A]}),
              [Body] = [P || {P, {body, <<"b">>}} <- rw_run:processes(Run)],
              ?assertEqual(A, node(Body)),
              ok = sys:suspend(Body),
              Report = receive {rw_crashed, Run, stalled, {gvt_stuck, _G, R}} -> R after 5000 -> ct:fail(no_watchdog) end,
              rw_timewarp:stop(H),
              [_Header, First | _] = string:split(Report, "\n", all),
              ?assertMatch({match, _}, re:run(First, "^body b \\(idx 1\\): step at LVT [0-9]+ .*[1-9][0-9]* unread messages")),
              ok
      end).

bad_nodes_are_refused(Config) ->
    {Scene, _} = proplists:get_value("pile_40", ?config(scenes, Config)),
    File = Scene#scene.file,
    {error, Message} = rigidwarp:run(File, #{nodes => 0}),
    ?assertNotEqual(nomatch, string:find(Message, "nodes")),
    {error, _} = rigidwarp:run(File, #{nodes => [not_a_node]}),
    {error, Unreachable} = rigidwarp:run(File, #{nodes => ['nobody_here@127.0.0.1']}),
    ?assertNotEqual(nomatch, string:find(Unreachable, "nobody_here@127.0.0.1")),
    ?assertEqual([], supervisor:which_children(rw_sims_sup)),
    ok.

%% The nodes connected now but not in Before, once given a few seconds to
%% go.
wait_for_nodes(Before) -> wait_for_nodes(Before, 100).

wait_for_nodes(Before, 0) -> nodes() -- Before;
wait_for_nodes(Before, Tries) ->
    case nodes() -- Before of
        [] -> [];
        _ -> timer:sleep(50), wait_for_nodes(Before, Tries - 1)
    end.
