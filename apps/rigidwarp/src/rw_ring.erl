%% The ring of the latest committed frames of one simulation, an ETS table
%% that the GVT process writes and anyone reads (the shell API, the viewer)
%% without asking a process. The ring names the frame times it holds; their
%% records stay where the bodies committed them (rw_commits) until the
%% frame leaves the ring, and readers select them from there: copying
%% every frame's records out of the records table and into the ring would
%% be a large share of the GVT process's work, which every body waits on.
%%
%% Keys: {t, Ms} => Tick for each frame held (its time in ms, an integer
%% when whole, rw_scene:whole_ms/1, and in ticks); {slot, K} => Ms for the
%% K-th frame modulo the ring's size; count => frames written; latest =>
%% Ms; source => {Records, N}, the records table and the number of bodies
%% in a frame. The ring and the records outlive the simulation's processes
%% (rw_run owns them), so a simulation restarted from a checkpoint writes
%% frames that are there already: they are the same frames, and stay.
-module(rw_ring).
-export([frames_kept/2, init/3, write/4, latest/1, frame_at/2, frames_after/3, ticks/1, truncate/2]).

%% The most body records a ring holds by default (about 200 bytes each,
%% 430-710 with rotation: 6.5-23 MB), and the fewest frames.
-define(MOST_RECORDS, (1 bsl 15)).
-define(FEWEST_FRAMES, 4).

%% How many frames a ring keeps for a scene of Bodies bodies: Frames, or
%% fewer, so that it holds at most 2^15 body records (the records of the
%% frames held stay in the records table, which every commit inserts
%% into), but not fewer than 4 for that.
-spec frames_kept(pos_integer(), non_neg_integer()) -> pos_integer().
frames_kept(Frames, Bodies) -> min(Frames, max(?FEWEST_FRAMES, ?MOST_RECORDS div max(1, Bodies))).

%% A ring over the records table Records of a simulation of N bodies.
-spec init(ets:tid(), ets:tid(), pos_integer()) -> ok.
init(Ring, Records, N) ->
    true = ets:insert(Ring, {source, Records, N}),
    _ = ets:insert_new(Ring, {count, 0}),
    ok.

%% Frame time Tick (Ms in ms) enters a ring of Size frames, unless it is
%% there already; the oldest leaves it once the ring is full, and the
%% caller forgets its records: {left, ItsTick}.
-spec write(ets:tid(), number(), non_neg_integer(), pos_integer()) -> ok | {left, non_neg_integer()}.
write(Ring, Ms, Tick, Size) ->
    case ets:member(Ring, {t, Ms}) of
        true -> ok;
        false -> add(Ring, Ms, Tick, Size)
    end.

add(Ring, Ms, Tick, Size) ->
    [{count, K}] = ets:lookup(Ring, count),
    Left = case K >= Size of
               true ->
                   [{_, OldMs}] = ets:lookup(Ring, {slot, K rem Size}),
                   [{_, OldTick}] = ets:lookup(Ring, {t, OldMs}),
                   true = ets:delete(Ring, {t, OldMs}),
                   {left, OldTick};
               false -> ok
           end,
    Latest = case ets:lookup(Ring, latest) of
                 [{latest, L}] when L > Ms -> L;
                 _ -> Ms
             end,
    true = ets:insert(Ring, [{{t, Ms}, Tick}, {{slot, K rem Size}, Ms}, {count, K + 1}, {latest, Latest}]),
    Left.

%% Drop the frames at From (ticks) and later: a simulation restarted from
%% a checkpoint at From commits them again, and a frame it writes must only
%% ever push older frames out of the ring (never one whose records the
%% restarted bodies have committed anew). The frames kept take the first
%% slots again, oldest first.
-spec truncate(ets:tid(), non_neg_integer()) -> ok.
truncate(Ring, From) ->
    Kept = lists:sort([{Ms, Tick} || [Ms, Tick] <- ets:match(Ring, {{t, '$1'}, '$2'}), Tick < From]),
    _ = ets:match_delete(Ring, {{t, '_'}, '_'}),
    _ = ets:match_delete(Ring, {{slot, '_'}, '_'}),
    true = ets:delete(Ring, latest),
    Slots = lists:zip(lists:seq(0, length(Kept) - 1), Kept),
    true = ets:insert(Ring, [{count, length(Kept)} | [{{t, Ms}, Tick} || {Ms, Tick} <- Kept]]
                              ++ [{{slot, K}, Ms} || {K, {Ms, _}} <- Slots]
                              ++ [{latest, Ms} || {Ms, _} <- lists:nthtail(max(0, length(Kept) - 1), Kept)]),
    ok.

%% The frame times the ring holds, in ticks.
-spec ticks(ets:tid()) -> [non_neg_integer()].
ticks(Ring) -> ets:select(Ring, [{{{t, '_'}, '$1'}, [], ['$1']}]).

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
            Bodies = rw_commits:select_at(Tick, Records),
            %% a frame leaving the ring while it was read is gone
            case length(Bodies) of
                N -> {frame, Ms, Bodies};
                _ -> none
            end;
        [] -> none
    end.

%% Up to Max frames of the ring after T ms, oldest first.
-spec frames_after(ets:tid(), number(), pos_integer()) -> [rw_reference:frame()].
frames_after(Ring, T, Max) ->
    Ts = lists:sort(ets:select(Ring, [{{{t, '$1'}, '_'}, [{'>', '$1', T}], ['$1']}])),
    [F || Ti <- lists:sublist(Ts, Max), F <- [frame_at(Ring, Ti)], F =/= none].
