%% The GVT counter of one simulation. Entities commit their state at every
%% sync point they move past (rw_commits: a record per body and a count per
%% sync point) and withdraw it when they roll back; the commit that
%% completes a sync point tells this process. Sync points complete in time
%% order: GVT advances to each, frame times enter the ring (rw_ring), and
%% entities and buckets drop their history before it (which raises every
%% LVT_ub to GVT + stride). GVT is published in an atomic that entities
%% read when they step; only an entity that cannot step until GVT reaches
%% some time asks to be woken then (wake_at/3), so an advance costs a
%% message per waiting entity, not one per body.
%%
%% Contact groups: at every regroup point X (a multiple of the period) it
%% plans the groups at S = X + period from the committed states at X
%% (rw_regroup:decide/4) and tells every entity whose group changes
%% ({regroup, S, Move}); GVT does not reach S before each of them has
%% answered (rolled back to S if it was past it, and stopped there).
%%
%% Messages it takes: {complete, T} (rw_commits), {wake_at, Pid, At},
%% {regroup_ack, S, Pid}; it sends {gvt, G} to whom asked to be woken, and
%% to its run (rw_run) {rw_frame, Gvt, Frame} or {rw_frame_time, Gvt, Ms}
%% for every frame, {rw_checkpoint, Gvt, Checkpoint} every checkpoint_ms of
%% wall time, and {rw_done, Gvt, EndMs}.
-module(rw_gvt).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/2, send_frames/1, wake_at/3, regroup_ack/3]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).
-export_type([options/0]).

%% run: told of every frame (the frame itself once send_frames/1 asks, else
%% its time), of checkpoints and of the end; ring_size: frames kept in the
%% ring; checkpoint_ms: wall time between checkpoints.
-type options() :: #{run => pid(), frames => boolean(), ring_size => pos_integer(),
                     checkpoint_ms => non_neg_integer()}.

-record(s, {
    sim :: #sim{},
    run :: pid() | undefined,
    frames = false :: boolean(),              % whole frames to the run, not their times
    gvt = -1 :: integer(),                   % last sync point passed
    complete = #{} :: #{non_neg_integer() => true},
    %% the entities to wake when GVT reaches each time, ascending (a few
    %% distinct times, each with up to every body: a list per time, where a
    %% set of {At, Pid} would hold an element per body)
    waiting = [] :: [{integer(), [pid()]}],
    ring_size :: pos_integer(),
    checkpoint_ms :: non_neg_integer(),
    checkpoint_due :: integer(),              % monotonic ms
    radii :: #{non_neg_integer() => float()},
    idxs :: [non_neg_integer()],                        % every body's idx, ascending
    groups :: rw_regroup:groups(),                      % the groups planned last
    pids = none :: none | #{non_neg_integer() => pid()},  % body idx => its process, once needed
    %% regroup points with entities that have not answered {regroup, S, _} yet
    unready = #{} :: #{non_neg_integer() => [pid()]},
    %% sync points passed since GVT was last published, newest first
    passed = [] :: [non_neg_integer()]
}).

-spec start_link(#sim{}, options()) -> {ok, pid()}.
start_link(Sim, Opts) -> gen_server:start_link(?MODULE, {Sim, Opts}, []).

%% From now on, send the run every frame, not only its time. Times suit a
%% run that counts frames or shows progress and would only drop the bodies'
%% states (a copy of every body's record per frame, made by this process,
%% which every entity may be waiting for).
-spec send_frames(pid()) -> ok.
send_frames(Gvt) -> gen_server:cast(Gvt, send_frames).

%% Send {gvt, G} to Pid once GVT G >= At (at once if it is already).
-spec wake_at(pid(), pid(), integer()) -> ok.
wake_at(Gvt, Pid, At) ->
    Gvt ! {wake_at, Pid, At},
    ok.

%% Entity Pid has stopped at regroup point S.
-spec regroup_ack(pid(), pid(), non_neg_integer()) -> ok.
regroup_ack(Gvt, Pid, S) ->
    Gvt ! {regroup_ack, S, Pid},
    ok.

-spec init({#sim{}, options()}) -> {ok, #s{}}.
init({#sim{scene = #scene{spheres = Spheres}, n = N, records = Records, ring = Ring, group_max = Max,
           grouping = Mode} = Sim, Opts}) ->
    %% Each advance brings the records of a frame or more onto this heap
    %% (held until GVT is published, for the regroup plan), and a heap
    %% sized to what survived the last collection would fill with them at
    %% once and collect at every advance: room for the records of about 40
    %% frames, at most 2M words (16 MiB), past which a heap costs more in
    %% cache misses than it saves in collections.
    _ = process_flag(min_heap_size, min(2048 * N, 1 bsl 21)),
    ok = rw_ring:init(Ring, Records, N),
    Idxs = lists:sort([I || #sphere{idx = I} <- Spheres]),
    Every = maps:get(checkpoint_ms, Opts, ?CHECKPOINT_MS),
    {ok, #s{sim = Sim, run = maps:get(run, Opts, undefined), frames = maps:get(frames, Opts, false),
            ring_size = maps:get(ring_size, Opts, 1024), idxs = Idxs, checkpoint_ms = Every,
            checkpoint_due = erlang:monotonic_time(millisecond) + Every,
            radii = maps:from_list([{I, R} || #sphere{idx = I, radius = R} <- Spheres]),
            groups = rw_regroup:new(Idxs, Max, Mode)}}.

%% GVT is read from the run (rw_run:gvt/1), which outlives this process.
-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, {error, unknown_call}, #s{}}.
handle_call(Req, _From, S) ->
    logger:warning("rw_gvt: unexpected call ~p", [Req]),
    {reply, {error, unknown_call}, S}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(send_frames, S) -> {noreply, S#s{frames = true}};
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({complete, T}, #s{complete = C, sim = #sim{profile = false}} = S) ->
    {noreply, advance(S#s{complete = more_complete(C#{T => true})})};
handle_info({complete, T}, #s{complete = C, sim = #sim{stats = Stats}} = S) ->
    {noreply, rw_stats:timed(Stats, gvt_reductions, fun() -> advance(S#s{complete = more_complete(C#{T => true})}) end)};
handle_info({regroup_ack, At, Pid}, #s{unready = U} = S) ->
    Left = lists:delete(Pid, maps:get(At, U)),
    S1 = case Left of
             [] -> S#s{unready = maps:remove(At, U)};
             _ -> S#s{unready = U#{At := Left}}
         end,
    {noreply, advance(S1)};
handle_info({wake_at, Pid, At}, #s{gvt = G} = S) when At =< G ->
    Pid ! {gvt, G},
    {noreply, S};
handle_info({wake_at, Pid, At}, #s{waiting = W} = S) ->
    {noreply, S#s{waiting = add_waiting(At, Pid, W)}};
handle_info(Msg, S) ->
    logger:warning("rw_gvt: unexpected message ~p", [Msg]),
    {noreply, S}.

ms(T, #s{sim = #sim{scene = Scene}}) -> rw_scene:ms(Scene, T).

%% An entity that commits several sync points in one step sends their
%% completions back to back: take them all, so that GVT advances over them
%% at once and entities and buckets hear of the last one only.
more_complete(C) ->
    receive
        {complete, T} -> more_complete(C#{T => true})
    after 0 -> C
    end.

%% Pass every sync point that is complete, then publish GVT, then write
%% the frames of the points passed and forget their records: every entity
%% may be waiting for GVT, and what it needs to step on (its regroup move,
%% whose entities must stop at their regroup point before they pass it) is
%% sent before GVT is published, the rest comes after.
advance(#s{gvt = G0} = S) ->
    #s{gvt = G, sim = #sim{end_t = End} = Sim, passed = Passed} = S1 = advance_over(S),
    case G > G0 of
        true ->
            ok = atomics:put(Sim#sim.gvt_now, 1, G),
            [rw_bucket:gvt(B, G) || B <- tuple_to_list(Sim#sim.buckets)],
            S2 = lists:foldl(fun finish/2, S1#s{waiting = wake(G, S1#s.waiting), passed = []},
                             lists:reverse(Passed)),
            ok = case G of
                     End -> notify(S#s.run, {rw_done, self(), ms(End, S)});
                     _ -> ok
                 end,
            S2;
        false ->
            S1
    end.

advance_over(#s{complete = C, sim = #sim{sync = Cal} = Sim, unready = U, gvt = G} = S) ->
    Next = rw_sync:after_gvt(G, Cal),
    %% not up to a regroup point whose entities have not all stopped there
    Held = map_size(U) > 0 andalso Next >= lists:min(maps:keys(U)),
    case (not Held) andalso maps:take(Next, C) of
        {true, C1} ->
            %% An entity told to stop at a regroup point rolls back to it and
            %% takes back its commits from it on, perhaps after their
            %% completions were sent: count again.
            case rw_commits:complete(Sim, Next) of
                true -> pass(Next, S#s{complete = C1});
                false -> S#s{complete = C1}
            end;
        _ ->
            S
    end.

%% GVT passes Next: plan the groups (advance/1 writes its frame once GVT
%% is published).
pass(Next, #s{sim = #sim{end_t = End}} = S) ->
    S1 = regroup(Next, S),
    S2 = S1#s{gvt = Next, passed = [Next | S1#s.passed]},
    case Next of
        End -> S2;
        _ -> advance_over(S2)
    end.

%% A sync point T that GVT has passed: put it in the ring if it is a
%% frame time (its records stay until it leaves the ring), else forget its
%% records.
finish(T, #s{sim = #sim{records = Records, ring = Ring, sync = Cal} = Sim} = S) ->
    ok = rw_commits:forget(Sim, T),
    case rw_sync:is_frame(T, Cal) of
        true ->
            %% frames leave the engine with their time in ms
            Ms = ms(T, S),
            ok = rw_ring:write(Ring, Ms, T, S#s.ring_size),
            ok = case S#s.frames of
                     true -> notify(S#s.run, {rw_frame, self(), {frame, Ms, rw_commits:select_at(T, Records)}});
                     false -> notify(S#s.run, {rw_frame_time, self(), Ms})
                 end,
            checkpoint(T, Ms, S);
        false ->
            ok = rw_commits:delete_at(T, Records),
            S
    end.

%% Every checkpoint_ms of wall time, a frame is also a checkpoint: the
%% whole state of every body, from which the run restarts after a fault.
checkpoint(T, Ms, #s{sim = #sim{records = Records, end_t = End}, checkpoint_due = Due} = S) when T < End ->
    Now = erlang:monotonic_time(millisecond),
    case Now >= Due of
        true ->
            ok = notify(S#s.run, {rw_checkpoint, self(), {checkpoint, T, Ms, rw_commits:states_at(T, Records)}}),
            S#s{checkpoint_due = Now + S#s.checkpoint_ms};
        false ->
            S
    end;
checkpoint(_T, _Ms, S) -> S.

%% At a regroup point X, plan the groups at X + period from the states
%% committed at X and the pairs the entities said met often lately, and
%% tell every entity whose group changes what to do then. Without a group
%% and without such a pair nothing can change, and nothing is planned.
regroup(X, #s{sim = #sim{sync = Cal, end_t = End}} = S) ->
    case rw_sync:period(Cal) of
        0 -> S;
        P when X rem P =/= 0; X + P >= End -> S;
        P -> regroup(X, P, S)
    end.

regroup(X, P, #s{sim = #sim{stats = Stats, met = MetTab}, groups = Groups} = S0) ->
    %% the pairs that met often since the last regroup point but one
    Met = maps:from_list([{Pair, true} || Pair <- ets:select(MetTab, [{{'$1', '$2'}, [{'>=', '$2', X - P}], ['$1']}])]),
    _ = ets:select_delete(MetTab, [{{'_', '$1'}, [{'<', '$1', X - P}], [true]}]),
    case rw_regroup:quiet(Met, Groups) of
        true ->
            S0;
        false ->
            #s{pids = Pids} = S = with_pids(S0),
            {Tell, Groups1} = rw_regroup:decide(committed(X, S), Met, Pids, Groups),
            At = X + P,
            Told = [begin Pid = maps:get(I, Pids), Pid ! {regroup, At, Move}, Pid end || {I, Move} <- Tell],
            ok = rw_stats:add(Stats, regroups, length(Told)),
            Unready = case Told of [] -> S#s.unready; _ -> (S#s.unready)#{At => Told} end,
            S#s{groups = Groups1, unready = Unready}
    end.

%% The bodies' processes (rw_sim_sup wrote them before the simulation
%% started).
with_pids(#s{pids = none, sim = #sim{procs = Procs}} = S) -> S#s{pids = maps:from_list(ets:tab2list(Procs))};
with_pids(S) -> S.

%% Every body's committed state at sync point X: {Idx, Radius, P, V}.
committed(X, #s{sim = #sim{records = Records}, radii = Radii, idxs = Idxs}) ->
    [{I, maps:get(I, Radii), Pos, V} || {I, {_, Pos, V, _, _}} <- lists:zip(Idxs, rw_commits:select_at(X, Records))].

add_waiting(At, Pid, [{A, _} = First | Rest]) when A < At -> [First | add_waiting(At, Pid, Rest)];
add_waiting(At, Pid, [{At, Pids} | Rest]) -> [{At, [Pid | Pids]} | Rest];
add_waiting(At, Pid, Later) -> [{At, [Pid]} | Later].

wake(G, [{At, Pids} | Rest]) when At =< G ->
    _ = [Pid ! {gvt, G} || Pid <- Pids],
    wake(G, Rest);
wake(_G, Waiting) -> Waiting.

notify(undefined, _) -> ok;
notify(Pid, Msg) -> Pid ! Msg, ok.
