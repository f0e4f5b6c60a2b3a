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
%% Backpressure: GVT passes no sync point once it has reached the
%% allowance the run keeps in an atomic (rw_flow: what the run's
%% subscribers have not handled yet bounds it), and goes on when the run
%% sends {allow, Tick}.
%%
%% Messages it takes: {complete, T} (rw_commits), {wake_at, Pid, At},
%% {regroup_ack, S, Pid}, {allow, Tick}; it sends {gvt, G} to whom asked
%% to be woken, and to its run (rw_run) {rw_frame, Gvt, Frame} or
%% {rw_frame_time, Gvt, Ms} for every frame, {rw_checkpoint, Gvt,
%% Checkpoint} every checkpoint_ms of wall time, and {rw_done, Gvt, EndMs}.
-module(rw_gvt).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/2, send_frames/1, wake_at/3, regroup_ack/3, sites/3]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).
-export_type([options/0]).

%% run: told of every frame (the frame itself once send_frames/1 asks, else
%% its time), of checkpoints and of the end; ring_size: frames kept in the
%% ring; checkpoint_ms: wall time between checkpoints; sweeper: forgets
%% the records this process is done with (rw_sweeper); flow: the
%% allowance, in slot 1 (rw_flow), none without.
-type options() :: #{run => pid(), frames => boolean(), ring_size => pos_integer(),
                     checkpoint_ms => non_neg_integer(), sweeper := pid(), flow => atomics:atomics_ref()}.

%% A simulation over several nodes: the GVT processes of the sites, those
%% that hold bodies (whose reports GVT waits for), the site of every body's
%% idx and process; what each site has reported whole ({T, Withdrawals});
%% the confirmation under way; the pairs that met often (Pair => T); the
%% regroup moves to send with the next GVT; the sync points whose records
%% are here.
-record(m, {
    sites :: [pid()],
    voters :: [pid()],
    site_of :: #{non_neg_integer() => non_neg_integer()},
    gvt_of :: #{pid() => pid()},
    reported = #{} :: #{non_neg_integer() => #{pid() => non_neg_integer()}},
    confirming = none :: none | {reference(), [non_neg_integer()], [pid()], [[non_neg_integer()]]},
    met = #{} :: #{{non_neg_integer(), non_neg_integer()} => non_neg_integer()},
    moves = [] :: [{pid(), term()}],
    have = #{} :: #{non_neg_integer() => true}
}).

-record(s, {
    sim :: #sim{},
    run :: pid() | undefined,
    frames = false :: boolean(),              % whole frames to the run, not their times
    gvt = -1 :: integer(),                   % last sync point passed
    complete = #{} :: #{non_neg_integer() => true},
    %% the entities to wake when GVT reaches each time
    waiting = rw_wakeups:new() :: rw_wakeups:wakeups(),
    ring_size :: pos_integer(),
    sweeper :: pid(),                         % forgets records (rw_sweeper)
    checkpoint_ms :: non_neg_integer(),
    checkpoint_due :: integer(),              % monotonic ms
    %% with sparse records, the sync point of the checkpoint announced
    checkpoint_at = none :: none | non_neg_integer(),
    radii :: #{non_neg_integer() => float()},
    groups :: rw_regroup:groups(),                      % the groups planned last
    pids = none :: none | #{non_neg_integer() => pid()},  % body idx => its process, once needed
    %% regroup points with entities that have not answered {regroup, S, _} yet
    unready = #{} :: #{non_neg_integer() => [pid()]},
    %% sync points passed since GVT was last published, newest first
    passed = [] :: [non_neg_integer()],
    buckets_told = -1 :: integer(),          % the GVT the buckets last heard of
    flow :: atomics:atomics_ref() | undefined,   % the allowance (rw_flow), written by the run
    %% on several nodes (rw_gvt_site): none on one
    multi = none :: none | #m{}
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
wake_at(Gvt, Pid, At) -> rw_trace:send(Gvt, {wake_at, Pid, At}).

%% Entity Pid has stopped at regroup point S.
-spec regroup_ack(pid(), pid(), non_neg_integer()) -> ok.
regroup_ack(Gvt, Pid, S) -> rw_trace:send(Gvt, {regroup_ack, S, Pid}).

%% On several nodes: the GVT process of every site (by the site's number),
%% the site of every body idx and the site GVT process of every body
%% process. Sent before any body starts.
-spec sites(pid(), [pid()], {#{non_neg_integer() => non_neg_integer()}, #{pid() => pid()}, [pid()]}) -> ok.
sites(Gvt, Sites, {SiteOf, GvtOf, Voters}) ->
    gen_server:call(Gvt, {sites, Sites, SiteOf, GvtOf, Voters}).

-spec init({#sim{}, options()}) -> {ok, #s{}}.
init({#sim{scene = #scene{spheres = Spheres, model = #model{gravity = Gravity}}, n = N, records = Records, ring = Ring, group_max = Max,
           grouping = Mode} = Sim, Opts}) ->
    %% Each advance brings the records of a frame or more onto this heap
    %% (held until GVT is published, for the regroup plan), and a heap
    %% sized to what survived the last collection would fill with them at
    %% once and collect at every advance: room for the records of about 40
    %% frames of up to 50 bodies, of fewer frames of more, and never past
    %% the 128k words beyond which the runtime hands a collection to a dirty
    %% scheduler (this process, which every body waits for, would wait for
    %% that thread to wake).
    _ = process_flag(min_heap_size, min(2048 * N, 100000)),
    ok = rw_trace:init(Sim#sim.trace),
    ok = rw_ring:init(Ring, Records, N),
    Idxs = lists:sort([I || #sphere{idx = I} <- Spheres]),
    Every = maps:get(checkpoint_ms, Opts, ?CHECKPOINT_MS),
    {ok, #s{sim = Sim, run = maps:get(run, Opts, undefined), frames = maps:get(frames, Opts, false),
            ring_size = maps:get(ring_size, Opts, 1024), sweeper = maps:get(sweeper, Opts),
            checkpoint_ms = Every, flow = maps:get(flow, Opts, undefined),
            checkpoint_due = erlang:monotonic_time(millisecond) + Every,
            radii = maps:from_list([{I, R} || #sphere{idx = I, radius = R} <- Spheres]),
            groups = rw_regroup:new(Idxs, Max, Mode, Gravity =/= undefined)}}.

%% GVT is read from the run (rw_run:gvt/1), which outlives this process.
-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, ok | {error, unknown_call}, #s{}}.
handle_call({sites, Sites, SiteOf, GvtOf, Voters}, _From, S) ->
    {reply, ok, S#s{multi = #m{sites = Sites, site_of = SiteOf, gvt_of = GvtOf, voters = Voters},
                    groups = rw_regroup:by_site(S#s.groups, SiteOf)}};
handle_call(Req, _From, S) ->
    logger:warning("rw_gvt: unexpected call ~p", [Req]),
    {reply, {error, unknown_call}, S}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(send_frames, S) -> {noreply, S#s{frames = true}};
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info(Msg, #s{sim = #sim{trace = undefined}} = S) -> info(Msg, S);
handle_info(Msg, S) -> rw_trace:task(gvt, Msg, fun() -> info(Msg, S) end).

info({complete, T}, #s{complete = C, sim = #sim{profile = false}} = S) ->
    {noreply, advance(S#s{complete = more_complete(C#{T => true})})};
info({complete, T}, #s{complete = C, sim = #sim{stats = Stats}} = S) ->
    {noreply, rw_stats:timed(Stats, gvt_reductions, fun() -> advance(S#s{complete = more_complete(C#{T => true})}) end)};
info({site_complete, Site, Whole}, #s{multi = M} = S) ->
    Reported = lists:foldl(fun({T, W}, R) -> maps:update_with(T, fun(By) -> By#{Site => W} end, #{Site => W}, R) end,
                           M#m.reported, Whole),
    {noreply, advance(S#s{multi = M#m{reported = Reported}})};
info({confirmed, Ref, Site, Confirmed, Rest, Records, Met}, #s{multi = #m{confirming = {Ref, _, _, _}}} = S) ->
    {noreply, confirmed(Site, Confirmed, Rest, Records, Met, S)};
info({regroup_ack, At, Pid}, #s{unready = U} = S) ->
    Left = lists:delete(Pid, maps:get(At, U)),
    S1 = case Left of
             [] -> S#s{unready = maps:remove(At, U)};
             _ -> S#s{unready = U#{At := Left}}
         end,
    {noreply, advance(S1)};
info({allow, _Tick}, S) ->
    {noreply, advance(S)};
info({wake_at, Pid, At}, #s{gvt = G} = S) when At =< G ->
    ok = rw_trace:send(Pid, {gvt, G}),
    {noreply, S};
info({wake_at, Pid, At}, #s{waiting = W} = S) ->
    {noreply, S#s{waiting = rw_wakeups:add(At, Pid, W)}};
info(Msg, S) ->
    logger:warning("rw_gvt: unexpected message ~p", [Msg]),
    {noreply, S}.

ms(T, #s{sim = #sim{scene = Scene}}) -> rw_scene:ms(Scene, T).

dt(#s{sim = #sim{scene = #scene{substep = Dt}}}) -> Dt.

%% An entity that commits several sync points in one step sends their
%% completions back to back: take them all, so that GVT advances over them
%% at once and entities and buckets hear of the last one only.
more_complete(C) ->
    receive
        {complete, T} = Msg ->
            ok = rw_trace:received(Msg),
            more_complete(C#{T => true})
    after 0 -> C
    end.

%% Pass every sync point that is complete, then publish GVT, then write
%% the frames of the points passed and forget their records: every entity
%% may be waiting for GVT, and what it needs to step on (its regroup move,
%% whose entities must stop at their regroup point before they pass it) is
%% sent before GVT is published, the rest comes after.
advance(#s{multi = #m{}} = S) ->
    confirm(S);
advance(#s{gvt = G0} = S) ->
    #s{gvt = G, sim = #sim{end_t = End} = Sim, passed = Passed} = S1 = advance_over(S),
    case G > G0 of
        true ->
            ok = rw_trace:committed(G),
            ok = atomics:put(Sim#sim.gvt_now, 1, G),
            Told = rw_bucket:gvt(tuple_to_list(Sim#sim.buckets), G, S1#s.buckets_told, dt(S)),
            S2 = lists:foldl(fun finish/2, S1#s{waiting = rw_wakeups:wake(G, S1#s.waiting), passed = [],
                                                buckets_told = Told},
                             lists:reverse(Passed)),
            ok = case G of
                     End -> done(S2);
                     _ -> ok
                 end,
            S2;
        false ->
            S1
    end.

%% GVT is at the end: once the records the run is done with are gone, say
%% so.
done(#s{sim = #sim{end_t = End}} = S) ->
    ok = rw_sweeper:sync(S#s.sweeper),
    notify(S#s.run, {rw_done, self(), ms(End, S)}).

advance_over(#s{complete = C, sim = #sim{sync = Cal} = Sim, gvt = G} = S) ->
    Next = rw_sync:after_gvt(G, Cal),
    case (not held(G, Next, S)) andalso maps:take(Next, C) of
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
%% records. On several nodes, only the frames whose records came here
%% enter the ring; of the others, the run hears the time, as of the frames
%% before T that are no sync points (nobody reads them).
finish(T, #s{sim = #sim{records = Records, ring = Ring, sync = Cal} = Sim} = S) ->
    ok = rw_commits:forget(Sim, T),
    ok = lists:foreach(fun(F) -> notify(S#s.run, {rw_frame_time, self(), ms(F, S)}) end, rw_sync:frames_before(T, Cal)),
    Here = case S#s.multi of
               none -> true;
               #m{have = Have} -> maps:is_key(T, Have)
           end,
    case rw_sync:is_frame(T, Cal) of
        true when not Here ->
            ok = notify(S#s.run, {rw_frame_time, self(), ms(T, S)}),
            S;
        true ->
            %% frames leave the engine with their time in ms
            Ms = ms(T, S),
            ok = case rw_ring:write(Ring, Ms, T, S#s.ring_size) of
                     ok -> ok;
                     {left, Old} -> rw_sweeper:forget(S#s.sweeper, Old)
                 end,
            ok = case S#s.frames of
                     true -> notify(S#s.run, {rw_frame, self(), {frame, Ms, rw_commits:select_at(T, Records)}});
                     false -> notify(S#s.run, {rw_frame_time, self(), Ms})
                 end,
            checkpoint(T, Ms, S);
        false ->
            ok = rw_sweeper:forget(S#s.sweeper, T),
            S
    end.

%% Every checkpoint_ms of wall time, a frame is also a checkpoint: the
%% whole state of every body, from which the run restarts after a fault.
%% When nobody reads the frames the bodies keep every record whole only at
%% the frame announced as the next checkpoint's, the first one at a sync
%% point that no body can have committed yet (past LVT_ub), so a
%% checkpoint comes about a stride later.
checkpoint(T, Ms, #s{sim = #sim{records_kept = whole, records = Records, end_t = End}, checkpoint_due = Due} = S)
  when T < End ->
    Now = erlang:monotonic_time(millisecond),
    case Now >= Due of
        true ->
            ok = notify(S#s.run, {rw_checkpoint, self(), {checkpoint, T, Ms, rw_commits:states_at(T, Records)}}),
            S#s{checkpoint_due = Now + S#s.checkpoint_ms};
        false ->
            S
    end;
checkpoint(_T, _Ms, #s{sim = #sim{records_kept = whole}} = S) -> S;
checkpoint(T, Ms, #s{sim = #sim{records = Records}, checkpoint_at = T} = S) ->
    ok = notify(S#s.run, {rw_checkpoint, self(), {checkpoint, T, Ms, rw_commits:states_at(T, Records)}}),
    S#s{checkpoint_due = erlang:monotonic_time(millisecond) + S#s.checkpoint_ms, checkpoint_at = none};
checkpoint(_T, _Ms, #s{sim = #sim{end_t = End, sync = Cal, scene = #scene{stride = Stride}} = Sim,
                       checkpoint_at = none, checkpoint_due = Due, gvt = G} = S) ->
    At = rw_sync:sync_frame_after(G + Stride, Cal),
    case At < End andalso erlang:monotonic_time(millisecond) >= Due of
        true ->
            ok = rw_commits:checkpoint_at(Sim, At),
            S#s{checkpoint_at = At};
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

regroup(X, P, #s{sim = #sim{stats = Stats}, groups = Groups} = S00) ->
    {Met, S0} = met_since(X - P, S00),
    case rw_regroup:quiet(Met, Groups) orelse not records_here(X, S0) of
        true ->
            S0;
        false ->
            #s{pids = Pids} = S = with_pids(S0),
            {Tell, Groups1} = rw_regroup:decide(committed(X, rw_regroup:wanted(Met, Groups), S), Met, Pids, Groups),
            At = X + P,
            Moves = [{maps:get(I, Pids), {regroup, At, Move}} || {I, Move} <- Tell],
            Told = [Pid || {Pid, _} <- Moves],
            ok = rw_stats:add(Stats, regroups, length(Told)),
            Unready = case Told of [] -> S#s.unready; _ -> (S#s.unready)#{At => Told} end,
            tell(Moves, S#s{groups = Groups1, unready = Unready})
    end.

%% The pairs that met often since Since (forgetting those before): on one
%% node from the table the entities write, on several from what the sites
%% sent (pairs of one site only: a contact group is one process, on one
%% node).
met_since(Since, #s{multi = none, sim = #sim{met = MetTab}} = S) ->
    Met = maps:from_list([{Pair, true} || Pair <- ets:select(MetTab, [{{'$1', '$2'}, [{'>=', '$2', Since}], ['$1']}])]),
    _ = ets:select_delete(MetTab, [{{'_', '$1'}, [{'<', '$1', Since}], [true]}]),
    {Met, S};
met_since(Since, #s{multi = #m{met = All} = M} = S) ->
    Recent = maps:filter(fun(_, T) -> T >= Since end, All),
    {maps:map(fun(_, _) -> true end, Recent), S#s{multi = M#m{met = Recent}}}.

records_here(_X, #s{multi = none}) -> true;
records_here(X, #s{multi = #m{have = Have}}) -> maps:is_key(X, Have).

%% On one node regroup moves go to their entities at once; on several, to
%% the entities' sites with the next GVT.
tell(Moves, #s{multi = none} = S) ->
    _ = [rw_trace:send(Pid, Msg) || {Pid, Msg} <- Moves],
    S;
tell(Moves, #s{multi = M} = S) ->
    S#s{multi = M#m{moves = M#m.moves ++ Moves}}.

%%% Several nodes (rw_gvt_site)

%% Ask the sites with bodies to confirm the sync points after GVT that all
%% of them have reported whole, up to the first regroup point, hold or the
%% end: one batch at a time.
confirm(#s{multi = #m{confirming = none} = M, gvt = G, sim = #sim{sync = Cal}} = S) ->
    case confirmable(G, rw_sync:after_gvt(G, Cal), S) of
        [] ->
            S;
        Ts ->
            Need = need(Ts, S),
            Ref = make_ref(),
            _ = [Site ! {confirm, Ref, [{T, maps:get(Site, maps:get(T, M#m.reported))} || T <- Ts], Need}
                 || Site <- M#m.voters],
            S#s{multi = M#m{confirming = {Ref, Ts, M#m.voters, []}, have = maps:merge(M#m.have, maps:from_keys(Need, true))}}
    end;
confirm(S) -> S.

confirmable(Prev, Next, #s{sim = #sim{sync = Cal, end_t = End}, multi = #m{reported = Reported, voters = Voters}} = S) ->
    Held = held(Prev, Next, S),
    Whole = case Reported of
                #{Next := By} -> lists:all(fun(V) -> maps:is_key(V, By) end, Voters);
                #{} -> false
            end,
    case (not Held) andalso Whole of
        false -> [];
        true when Next >= End -> [Next];
        true ->
            %% a batch ends at a regroup point where groups may change (the
            %% plan there holds GVT before the next), and goes on past one
            %% where nothing can
            case regroup_point(Next, S) andalso not quiet_at(Next, S) of
                true -> [Next];
                false -> [Next | confirmable(Next, rw_sync:after_gvt(Next, Cal), S)]
            end
    end.

quiet_at(X, #s{sim = #sim{sync = Cal}, groups = Groups} = S) ->
    rw_regroup:quiet(element(1, met_since(X - rw_sync:period(Cal), S)), Groups).

regroup_point(X, #s{sim = #sim{sync = Cal, end_t = End}}) ->
    case rw_sync:period(Cal) of
        0 -> false;
        P -> X rem P =:= 0 andalso X + P < End
    end.

%% The sync points of a batch whose records must come here: the frames the
%% run shows or keeps (all when it asked for frames or its ring keeps more
%% than one, else the last), a checkpoint when one is due, regroup points
%% where contact groups may change.
need(Ts, #s{sim = #sim{sync = Cal, end_t = End}} = S) ->
    Frames = [T || T <- Ts, rw_sync:is_frame(T, Cal)],
    Shown = [T || T <- Frames, S#s.frames orelse S#s.ring_size > 1 orelse T =:= End],
    Check = case erlang:monotonic_time(millisecond) >= S#s.checkpoint_due of
                true -> lists:sublist(lists:reverse([T || T <- Frames, T < End]), 1);
                false -> []
            end,
    Regroup = [X || X <- Ts, regroup_point(X, S), not quiet_at(X, S)],
    lists:usort(Shown ++ Check ++ Regroup).

%% A site's answer: its records of the sync points it confirmed, the pairs
%% that met, what it knows now of the others. Once every site has
%% answered, GVT passes the sync points every site confirmed.
confirmed(Site, Confirmed, Rest, Records, Met, #s{sim = Sim, multi = M} = S) ->
    true = ets:insert(Sim#sim.records, Records),
    SiteOf = M#m.site_of,
    Met1 = lists:foldl(fun({{A, B} = Pair, T}, Acc) ->
                               case maps:get(A, SiteOf) =:= maps:get(B, SiteOf) of
                                   true -> maps:update_with(Pair, fun(T0) -> max(T0, T) end, T, Acc);
                                   false -> Acc
                               end
                       end, M#m.met, Met),
    Reported = lists:foldl(fun({T, none}, R) -> maps:update_with(T, fun(By) -> maps:remove(Site, By) end, #{}, R);
                              ({T, W}, R) -> maps:update_with(T, fun(By) -> By#{Site => W} end, #{Site => W}, R)
                           end, M#m.reported, Rest),
    {Ref, Ts, Pending, Answers} = M#m.confirming,
    case lists:delete(Site, Pending) of
        [] ->
            Passable = lists:sublist(Ts, lists:min([length(C) || C <- [Confirmed | Answers]])),
            #s{gvt = G, multi = M1} = S1 = pass_confirmed(Passable, S#s{multi = M#m{met = Met1, reported = Reported,
                                                                                    confirming = none}}),
            %% the records of the sync points not passed are asked for again
            Later = [T || T <- Ts, T > G],
            _ = [rw_commits:delete_at(T, Sim#sim.records) || T <- Later, is_map_key(T, M1#m.have)],
            confirm(publish(S#s.gvt, S1#s{multi = M1#m{have = maps:without(Later, M1#m.have)}}));
        Left ->
            S#s{multi = M#m{met = Met1, reported = Reported, confirming = {Ref, Ts, Left, [Confirmed | Answers]}}}
    end.

%% In order, up to a regroup point's plan: a batch may go past a regroup
%% point that was quiet when it was asked for and has pairs that met since,
%% and the entities told to stop at the next one must hear it before GVT
%% passes it (the sync points left are confirmed again later).
pass_confirmed([], S) -> S;
pass_confirmed([T | Ts], S) ->
    case regroup_held(T, S) of
        true ->
            S;
        false ->
            S1 = regroup(T, S),
            pass_confirmed(Ts, S1#s{gvt = T, passed = [T | S1#s.passed]})
    end.

%% GVT has passed the sync points confirmed: every site hears it, with the
%% regroup moves for its entities first; then the frames.
publish(G0, #s{gvt = G} = S) when G =< G0 -> S;
publish(_G0, #s{gvt = G, sim = #sim{end_t = End} = Sim, multi = M, passed = Passed} = S) ->
    ok = atomics:put(Sim#sim.gvt_now, 1, G),
    GvtOf = M#m.gvt_of,
    _ = [Site ! {gvt, G, [{Pid, Msg} || {Pid, Msg} <- M#m.moves, maps:get(Pid, GvtOf) =:= Site]} || Site <- M#m.sites],
    S1 = lists:foldl(fun finish/2, S#s{passed = [], multi = M#m{moves = []}}, lists:reverse(Passed)),
    #s{multi = M1} = S1,
    S2 = S1#s{multi = M1#m{reported = maps:filter(fun(T, _) -> T > G end, M1#m.reported),
                           have = maps:filter(fun(T, _) -> T > G end, M1#m.have)}},
    ok = case G of
             End -> done(S2);
             _ -> ok
         end,
    S2.

%% GVT at G (or a batch up to G) does not pass sync point Next: not up to
%% a regroup point whose entities have not all stopped there, nor past
%% the allowance.
held(G, Next, S) -> regroup_held(Next, S) orelse flow_held(G, S).

regroup_held(T, #s{unready = U}) -> map_size(U) > 0 andalso T >= lists:min(maps:keys(U)).

%% GVT at G (or a batch up to G) goes no further: the run's subscribers
%% have not handled enough of the frames before it.
flow_held(_G, #s{flow = undefined}) -> false;
flow_held(G, #s{flow = Flow}) -> rw_flow:held(G, atomics:get(Flow, 1)).

%% The bodies' processes (rw_sim_sup wrote them before the simulation
%% started).
with_pids(#s{pids = none, sim = #sim{procs = Procs}} = S) -> S#s{pids = maps:from_list(ets:tab2list(Procs))};
with_pids(S) -> S.

%% The committed states of bodies Idxs (all: every body) at sync point X:
%% {Idx, Radius, P, V}.
committed(X, Idxs, #s{sim = #sim{records = Records}, radii = Radii}) ->
    [{I, maps:get(I, Radii), Pos, V} || {I, Pos, V} <- rw_commits:motions_at(X, Idxs, Records)].


notify(undefined, _) -> ok;
notify(Pid, Msg) -> Pid ! Msg, ok.
