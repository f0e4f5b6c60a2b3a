%% The GVT counter of one simulation. Bodies commit their state at every
%% frame time they move past (rw_body: an ETS record plus a shared counter)
%% and withdraw it when they roll back; the body whose commit completes a
%% frame time tells this process. Frames complete in time order: GVT
%% advances to each, it enters the ETS ring, and bodies and buckets drop
%% their history before it (which raises every LVT_ub to GVT + stride).
%% The ring names the frame times it holds; their records stay where the
%% bodies committed them until the frame leaves the ring, and readers
%% select them from there (a copy out of the records table and one into
%% the ring took this process a third of its time on Parallel 500).
%% GVT is published in an atomic that bodies read when they step; only a
%% body that cannot step until GVT reaches some time asks to be woken then
%% (wake_at/3), so an advance costs a message per waiting body, not one
%% per body.
%%
%% Contact groups: at every regroup point X (a multiple of #sim.period)
%% it plans the groups at S = X + period from the committed states at X
%% (rw_regroup), writes who moves then into the plans table, and tells
%% every entity whose group changes ({regroup, S}); GVT does not reach S
%% before each of them has answered (rolled back to S if it was past it,
%% and stopped there).
%%
%% A watchdog stops the run with a diagnostic naming every body's phase,
%% LVT and awaited acknowledgements if GVT does not advance for a while.
-module(rw_gvt).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/0, go/4, subscribe/2, subscribe/3, latest/1, frame_at/2, frames_after/3, gvt/1, sync_after/2, wake_at/3]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-record(s, {
    sim :: #sim{} | undefined,
    bodies = [] :: [pid()],
    owner :: pid() | undefined,
    subscribers = [] :: [{pid(), frames | times}],
    gvt = -1 :: integer(),                   % last frame time written
    complete = #{} :: #{non_neg_integer() => true},
    %% the bodies to wake when GVT reaches each time, ascending (a few
    %% distinct times, each with up to every body: a set of {At, Pid} cost
    %% the GVT process a third of its time on Parallel 500)
    waiting = [] :: [{integer(), [pid()]}],
    last_advance :: integer() | undefined,
    watchdog_ms = 10000 :: pos_integer(),
    ring_size = 1024 :: pos_integer(),
    frames = 0 :: non_neg_integer(),
    pids = #{} :: #{non_neg_integer() => pid()},        % body idx => process
    radii = #{} :: #{non_neg_integer() => float()},
    idxs = [] :: [non_neg_integer()],                   % every body's idx, ascending
    leaders = #{} :: rw_regroup:leaders(),              % the groups planned last
    grouped = false :: boolean(),                       % ... and whether any has two bodies or more
    %% regroup points with entities that have not answered {regroup, S} yet
    unready = #{} :: #{non_neg_integer() => [pid()]},
    %% sync points passed since GVT was last published, newest first
    passed = [] :: [non_neg_integer()]
}).

-spec start_link() -> {ok, pid()}.
start_link() -> gen_server:start_link(?MODULE, [], []).

%% Start counting: Opts may set watchdog_ms and ring_size.
-spec go(pid(), #sim{}, [pid()], map()) -> ok.
go(Gvt, Sim, Bodies, Opts) -> gen_server:call(Gvt, {go, Sim, Bodies, Opts}).

%% Send {rw_frame, Gvt, Frame} to Pid for every frame from now on.
-spec subscribe(pid(), pid()) -> ok.
subscribe(Gvt, Pid) -> subscribe(Gvt, Pid, frames).

%% As subscribe/2 (frames), or only each frame's time in ms:
%% {rw_frame_time, Gvt, T}, for a subscriber that counts frames or shows
%% progress and would only drop the bodies' states (a copy of every
%% body's record per frame, made by this process, which every body may be
%% waiting for).
-spec subscribe(pid(), pid(), frames | times) -> ok.
subscribe(Gvt, Pid, What) when What =:= frames; What =:= times -> gen_server:call(Gvt, {subscribe, Pid, What}).

%% Send {gvt, G} to Pid once GVT G >= At (at once if it is already).
-spec wake_at(pid(), pid(), integer()) -> ok.
wake_at(Gvt, Pid, At) ->
    Gvt ! {wake_at, Pid, At},
    ok.

%% GVT in ms (-1 before the first frame).
-spec gvt(pid()) -> number().
gvt(Gvt) -> gen_server:call(Gvt, gvt).

%% Frames are read from the ring directly, without the GVT process. The
%% ring holds their times in ms, an integer when whole (rw_scene:whole_ms/1),
%% each with its tick, and where the records are: {source, Records, N}.
-spec latest(ets:tid()) -> rw_reference:frame() | none.
latest(Ring) ->
    case ets:lookup(Ring, latest) of
        [{latest, T}] -> frame_at(Ring, T);
        [] -> none
    end.

-spec frame_at(ets:tid(), number()) -> rw_reference:frame() | none.
frame_at(Ring, T) ->
    Ms = rw_scene:whole_ms(T),
    case ets:lookup(Ring, {t, Ms}) of
        [{_, Tick}] ->
            [{source, Records, N}] = ets:lookup(Ring, source),
            Bodies = select_at(Tick, Records),
            %% a frame leaving the ring while it was read is gone
            case length(Bodies) of
                N -> {frame, Ms, Bodies};
                _ -> none
            end;
        [] -> none
    end.

%% Up to Max frames of the ring after T, oldest first.
-spec frames_after(ets:tid(), number(), pos_integer()) -> [rw_reference:frame()].
frames_after(Ring, T, Max) ->
    Ts = lists:sort(ets:select(Ring, [{{{t, '$1'}, '_'}, [{'>', '$1', T}], ['$1']}])),
    [F || Ti <- lists:sublist(Ts, Max), F <- [frame_at(Ring, Ti)], F =/= none].

-spec init([]) -> {ok, #s{}}.
init([]) -> {ok, #s{}}.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call({go, #sim{scene = #scene{spheres = Spheres}} = Sim, Bodies, Opts}, _From, S) ->
    Watchdog = maps:get(watchdog_ms, Opts, 10000),
    erlang:send_after(Watchdog div 4 + 1, self(), watchdog),
    Idxs = [I || #sphere{idx = I} <- Spheres],
    %% Each advance brings the records of a frame or more onto this heap
    %% (held until GVT is published, for the regroup plan), and a heap
    %% sized to what survived the last collection fills with them at once:
    %% with room for the records of about 40 frames, this process was
    %% scheduled in 27 % less of a Cylinders 500 run (0.7 s, not 1.0 s).
    %% (at most 2M words, 16 MiB: 4M made Cylinders 500 slower than 1M)
    _ = process_flag(min_heap_size, min(2048 * length(Idxs), 1 bsl 21)),
    true = ets:insert(Sim#sim.ring, {source, Sim#sim.records, length(Idxs)}),
    {reply, ok, S#s{sim = Sim, bodies = Bodies, owner = maps:get(owner, Opts, undefined),
                    watchdog_ms = Watchdog, ring_size = maps:get(ring_size, Opts, 1024),
                    last_advance = now_ms(), pids = maps:from_list(lists:zip(Idxs, Bodies)),
                    radii = maps:from_list([{I, R} || #sphere{idx = I, radius = R} <- Spheres]),
                    idxs = lists:sort(Idxs),
                    leaders = maps:from_list([{I, I} || I <- Idxs])}};
handle_call({subscribe, Pid, What}, _From, #s{subscribers = Subs} = S) ->
    {reply, ok, S#s{subscribers = [{Pid, What} | Subs]}};
handle_call(gvt, _From, #s{gvt = G} = S) ->
    {reply, ms(G, S), S}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}} | {stop, term(), #s{}}.
handle_info({complete, T}, #s{complete = C, sim = #sim{profile = false}} = S) ->
    {noreply, advance(S#s{complete = more_complete(C#{T => true})})};
handle_info({complete, T}, #s{complete = C, sim = #sim{stats = Stats}} = S) ->
    T0 = reductions(),
    S1 = advance(S#s{complete = more_complete(C#{T => true})}),
    %% counter 10 is gvt_reductions (rw_timewarp's stat names)
    counters:add(Stats, 10, reductions() - T0),
    {noreply, S1};
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
handle_info(watchdog, #s{gvt = End, sim = #sim{end_t = End}} = S) ->
    {noreply, S};
handle_info(watchdog, #s{last_advance = Last, watchdog_ms = W} = S) ->
    case now_ms() - Last > W of
        true ->
            Report = diagnose(S),
            logger:error("rigidwarp: GVT stuck at ~p ms for ~b ms~n~ts", [ms(S#s.gvt, S), W, Report]),
            ok = notify(S#s.owner, {rw_stalled, self(), ms(S#s.gvt, S), Report}),
            {noreply, S#s{last_advance = now_ms()}};
        false ->
            erlang:send_after(W div 4 + 1, self(), watchdog),
            {noreply, S}
    end;
handle_info(Msg, S) ->
    logger:warning("rw_gvt: unexpected message ~p", [Msg]),
    {noreply, S}.

%% GVT advances through the sync points: frame times, multiples of the
%% stride, and the end time. Frames are written at frame times only.
next_sync(#s{gvt = G, sim = Sim}) -> sync_after(G, Sim).

%% The first sync point after G (G < 0: before the first frame): the next
%% frame time, multiple of the stride or regroup point, or the end. Bodies
%% use it too: GVT cannot pass it before every body has reached it.
-spec sync_after(integer(), #sim{}) -> non_neg_integer().
sync_after(G, _Sim) when G < 0 -> 0;
sync_after(G, #sim{scene = #scene{frame = F, stride = S}, period = P, end_t = End}) ->
    Regroup = case P of 0 -> End; _ -> (G div P + 1) * P end,
    lists:min([(G div F + 1) * F, (G div S + 1) * S, Regroup, End]).

is_frame(T, #sim{scene = #scene{frame = F}, end_t = End}) -> T rem F =:= 0 orelse T =:= End.

ms(T, #s{sim = #sim{scene = Scene}}) -> rw_scene:ms(Scene, T);
ms(T, #s{sim = undefined}) -> T.

%% A body that commits several sync points in one step sends their
%% completions back to back: take them all, so that GVT advances over them
%% at once and bodies and buckets hear of the last one only.
more_complete(C) ->
    receive
        {complete, T} -> more_complete(C#{T => true})
    after 0 -> C
    end.

%% Pass every sync point that is complete, then publish GVT, then write
%% the frames of the points passed and forget their records: every body
%% may be waiting for GVT, and what it needs to step on (the regroup plans,
%% whose entities must stop at their regroup point before they pass it) is
%% ready before GVT is published, the rest comes after.
advance(#s{gvt = G0} = S) ->
    #s{gvt = G, sim = #sim{end_t = End} = Sim, passed = Passed} = S1 = advance_over(S),
    case G > G0 of
        true ->
            ok = atomics:put(Sim#sim.gvt_now, 1, G),
            [rw_bucket:gvt(B, G) || B <- tuple_to_list(Sim#sim.buckets)],
            S2 = lists:foldl(fun finish/2, S1#s{waiting = wake(G, S1#s.waiting), passed = []},
                             lists:reverse(Passed)),
            ok = case G of
                     End -> notify(S#s.owner, {rw_done, self(), ms(End, S)});
                     _ -> ok
                 end,
            S2;
        false ->
            S1
    end.

advance_over(#s{complete = C, sim = Sim, unready = U} = S) ->
    Next = next_sync(S),
    %% not up to a regroup point whose entities have not all stopped there
    Held = map_size(U) > 0 andalso Next >= lists:min(maps:keys(U)),
    case (not Held) andalso maps:take(Next, C) of
        {true, C1} ->
            %% An entity told to stop at a regroup point rolls back to it and
            %% takes back its commits from it on, perhaps after their
            %% completions were sent: count again.
            case ets:lookup(Sim#sim.counts, Next) of
                [{_, N}] when N =:= Sim#sim.n -> pass(Next, S#s{complete = C1});
                _ -> S#s{complete = C1}
            end;
        _ ->
            S
    end.

%% GVT passes Next: plan the groups (advance/1 writes its frame once GVT
%% is published).
pass(Next, #s{sim = #sim{end_t = End}} = S) ->
    S1 = regroup(Next, S),
    S2 = S1#s{gvt = Next, last_advance = now_ms(), passed = [Next | S1#s.passed]},
    case Next of
        End -> S2;
        _ -> advance_over(S2)
    end.

%% A sync point T that GVT has passed: put it in the ring if it is a
%% frame time (its records stay until it leaves the ring), else forget its
%% records.
finish(T, #s{sim = Sim} = S) ->
    ets:delete(Sim#sim.counts, T),
    case is_frame(T, Sim) of
        true ->
            %% frames leave the engine with their time in ms
            Ms = ms(T, S),
            write_ring(Ms, T, S),
            Subs = S#s.subscribers,
            Frame = case lists:keymember(frames, 2, Subs) of
                        true -> {frame, Ms, select_at(T, Sim#sim.records)};
                        false -> none
                    end,
            _ = [case What of
                     frames -> P ! {rw_frame, self(), Frame};
                     times -> P ! {rw_frame_time, self(), Ms}
                 end || {P, What} <- Subs],
            S#s{frames = S#s.frames + 1};
        false ->
            _ = delete_records(T, Sim),
            S
    end.

delete_records(T, #sim{records = Records}) ->
    ets:select_delete(Records, [{{{T, '_'}, '_'}, [], [true]}]).

%% At a regroup point X, plan the groups at X + period from the states
%% committed at X and the pairs the bodies said met often lately, and
%% write who moves then. Without a group and without such a pair nothing
%% can change, and nothing is planned.
regroup(_X, #s{sim = #sim{period = 0}} = S) -> S;
regroup(X, #s{sim = #sim{period = P, end_t = End}} = S) when X rem P =/= 0; X + P >= End -> S;
regroup(X, #s{sim = #sim{period = P, group_max = Max, grouping = Mode, plans = Plans, stats = Stats, met = MetTab},
              leaders = Old, pids = Pids, grouped = Grouped} = S) ->
    %% the pairs that met often since the last regroup point but one
    Met = maps:from_list([{Pair, true} || Pair <- ets:select(MetTab, [{{'$1', '$2'}, [{'>=', '$2', X - P}], ['$1']}])]),
    ets:select_delete(MetTab, [{{'_', '$1'}, [{'<', '$1', X - P}], [true]}]),
    case Mode =:= persistent andalso not Grouped andalso map_size(Met) =:= 0 of
        true ->
            S;
        false ->
            New = rw_regroup:plan(committed(X, S), Old, Max, case Mode of eager -> eager; persistent -> Met end),
            Moves = rw_regroup:moves(Old, New, Pids),
            At = X + P,
            ets:insert(Plans, [{{At, I}, Move} || {I, Move} <- maps:to_list(Moves)]),
            %% plans before the last regroup point are done with
            ets:select_delete(Plans, [{{{'$1', '_'}, '_'}, [{'<', '$1', X}], [true]}]),
            Told = [begin Pid = maps:get(I, Pids), Pid ! {regroup, At}, Pid end
                    || {I, #{send := _}} <- maps:to_list(Moves)],
            %% counter 13 is regroups: groups that change
            counters:add(Stats, 13, length(Told)),
            Unready = case Told of [] -> S#s.unready; _ -> (S#s.unready)#{At => Told} end,
            S#s{leaders = New, grouped = lists:any(fun({I, L}) -> I =/= L end, maps:to_list(New)), unready = Unready}
    end.

%% Every body's committed state at sync point X: {Idx, Radius, P, V}.
committed(X, #s{sim = Sim, radii = Radii, idxs = Idxs}) ->
    [{I, maps:get(I, Radii), Pos, V} || {I, {_, Pos, V, _, _}} <- lists:zip(Idxs, select_at(X, Sim#sim.records))].

%% The records committed at sync point T, in idx order (the table is
%% ordered by {T, Idx}): one per body once GVT has passed T.
select_at(T, Records) -> ets:select(Records, [{{{T, '_'}, '$1'}, [], ['$1']}]).

add_waiting(At, Pid, [{A, _} = First | Rest]) when A < At -> [First | add_waiting(At, Pid, Rest)];
add_waiting(At, Pid, [{At, Pids} | Rest]) -> [{At, [Pid | Pids]} | Rest];
add_waiting(At, Pid, Later) -> [{At, [Pid]} | Later].

wake(G, [{At, Pids} | Rest]) when At =< G ->
    _ = [Pid ! {gvt, G} || Pid <- Pids],
    wake(G, Rest);
wake(_G, Waiting) -> Waiting.

%% Frame time Tick (Ms in ms) enters the ring; the oldest leaves it once
%% the ring is full, and its records go.
write_ring(Ms, Tick, #s{sim = Sim, ring_size = Size, frames = K}) ->
    Ring = Sim#sim.ring,
    _ = case K >= Size of
            true ->
                [{_, OldMs}] = ets:lookup(Ring, {slot, K rem Size}),
                [{_, OldTick}] = ets:lookup(Ring, {t, OldMs}),
                ets:delete(Ring, {t, OldMs}),
                delete_records(OldTick, Sim);
            false -> 0
        end,
    ets:insert(Ring, [{{t, Ms}, Tick}, {{slot, K rem Size}, Ms}, {latest, Ms}]).

notify(undefined, _) -> ok;
notify(Pid, Msg) -> Pid ! Msg, ok.

%% Who waits on whom: each body's phase, LVT, what it awaits and how many
%% messages it has not read yet, the bodies holding GVT back first.
diagnose(#s{bodies = Bodies}) ->
    Lines = [try sys:get_state(B, 500) of
                 {Phase, D} -> {rw_body:lvt(D), [rw_body:describe(Phase, D), queue(B)]}
             catch
                 exit:_ -> {-1, io_lib:format("~p: not answering (blocked in a bucket call?)~ts", [B, queue(B)])}
             end || B <- Bodies],
    lists:flatten(["bodies by LVT, lowest (holding GVT back) first:\n"
                   | [[L, $\n] || {_, L} <- lists:keysort(1, Lines)]]).

queue(Pid) ->
    case erlang:process_info(Pid, message_queue_len) of
        {message_queue_len, N} -> io_lib:format("; ~b unread messages", [N]);
        undefined -> "; dead"
    end.

now_ms() -> erlang:monotonic_time(millisecond).

%% Work done by this process so far (profiling counts reductions, which
%% preemption does not inflate as it does wall time).
reductions() -> element(2, erlang:process_info(self(), reductions)).
