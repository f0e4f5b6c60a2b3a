-module(rw_bucket_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("rw_physics/include/rw_physics.hrl").

%% The buckets hear of GVT when it has moved on by a sweep's worth since
%% they last did (rw_cells:gc/2 would ignore anything sooner), and always
%% the first time.
gvt_tells_the_buckets_only_when_they_sweep_test() ->
    Dt = 1000,
    Every = rw_cells:sweep_every(Dt),
    Buckets = [self(), self()],
    ?assertEqual(0, rw_bucket:gvt(Buckets, 0, -1, Dt)),
    ?assertEqual([0, 0], told()),
    ?assertEqual(0, rw_bucket:gvt(Buckets, Every - Dt, 0, Dt)),
    ?assertEqual([], told()),
    ?assertEqual(Every + Dt, rw_bucket:gvt(Buckets, Every + Dt, 0, Dt)),
    ?assertEqual([Every + Dt, Every + Dt], told()).

%% Told only then, a bucket sweeps at the same GVTs as when told of every
%% sync point (rw_cells:gc/2 changes its cells exactly when it sweeps).
sweeps_at_the_gvts_it_is_told_test() ->
    Dt = 1000,
    Gvts = lists:seq(0, 200 * Dt, 10 * Dt) ++ lists:seq(201 * Dt, 300 * Dt, 7 * Dt),
    Cells = rw_cells:new(#model{}, Dt),
    {_, Told} = lists:foldl(fun(G, {T, Acc}) ->
                                    case rw_bucket:gvt([self()], G, T, Dt) of
                                        T -> {T, Acc};
                                        T1 -> {T1, [T1 | Acc]}
                                    end
                            end, {-1, []}, Gvts),
    _ = told(),
    {_, Swept} = lists:foldl(fun(G, {C, Acc}) ->
                                     case rw_cells:gc(G, C) of
                                         C -> {C, Acc};
                                         C1 -> {C1, [G | Acc]}
                                     end
                             end, {Cells, []}, Gvts),
    ?assert(length(Swept) > 5),
    ?assertEqual(lists:reverse(Swept), lists:reverse(Told)).

told() ->
    receive {'$gen_cast', {gvt, G}} -> [G | told()]
    after 0 -> []
    end.

%% A bucket runs at high priority, and so does its caller while it waits
%% for the answer: the request is served, and the caller resumes, before
%% the runnable bodies of normal priority. After the call the caller has
%% its own priority again, whatever it was.
callers_wait_at_high_priority_test() ->
    {ok, Bucket} = rw_bucket:start_link(#model{}, 1, erlang, undefined, undefined, 233),
    ?assertEqual({priority, high}, process_info(Bucket, priority)),
    unlink(Bucket),
    exit(Bucket, shutdown),
    Write = {self(), 0, #{}, {0, 0, 0, 0, 0, 0}},
    %% a stand-in bucket answers with the caller's priority as it asks
    Answering = fun Loop() ->
                        receive
                            {'$rw_call', {Caller, Ref}, _} ->
                                {priority, P} = process_info(Caller, priority),
                                Caller ! {Ref, P},
                                Loop();
                            stop -> ok
                        end
                end,
    Fake = spawn_link(Answering),
    ?assertEqual(high, rw_bucket:lock_probe(Fake, [], Write, [])),
    ?assertEqual({priority, normal}, process_info(self(), priority)),
    ?assertEqual(high, rw_bucket:lock_delete(Fake, self(), [], [], 0)),
    ?assertEqual({priority, normal}, process_info(self(), priority)),
    Low = process_flag(priority, low),
    ?assertEqual(high, rw_bucket:probe_commit(Fake, [], Write, [], 0)),
    ?assertEqual({priority, low}, process_info(self(), priority)),
    process_flag(priority, Low),
    Fake ! stop.
