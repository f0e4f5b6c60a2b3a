%% The sync calendar of a Time Warp simulation (pure): the times at which
%% every entity commits its state and GVT may stop. Sync points are the
%% frame times, the multiples of the stride, the regroup points (multiples
%% of the period, when contact groups are on) and the end time. GVT
%% advances from one sync point to the next once every body has committed
%% it; a body that waits for GVT asks to be woken at a sync point.
%%
%% When nobody reads the frames, only every Nth frame time need be a sync
%% point (sparse/2): a frame in between is only a time the run hears of.
%% Every body commits at every sync point, a cost of its own to a body
%% that flies a whole stride alone.
-module(rw_sync).
-export([new/4, new/5, sparse/2, start/1, is_sync/2, next_at/2, is_frame/2, frames_before/2, sync_frame_after/2,
         after_gvt/2, last_before/2, end_t/1, period/1]).
-export_type([calendar/0]).

-record(cal, {
    frame :: pos_integer(),          % ticks
    sync_frame :: pos_integer(),     % the frame times that are sync points: a multiple of frame
    stride :: pos_integer(),
    end_t :: non_neg_integer(),
    period :: non_neg_integer(),     % regroup points; 0: no contact groups
    start = 0 :: non_neg_integer()   % the first sync point: the time the run starts from
}).
-opaque calendar() :: #cal{}.

-spec new(pos_integer(), pos_integer(), non_neg_integer(), non_neg_integer()) -> calendar().
new(Frame, Stride, End, Period) -> new(Frame, Stride, End, Period, 0).

%% A calendar for a run that starts at Start, a frame time (a run resumed
%% from a checkpoint): sync points and frames fall where they fall in the
%% run from 0, so that the frames are the same.
-spec new(pos_integer(), pos_integer(), non_neg_integer(), non_neg_integer(), non_neg_integer()) -> calendar().
new(Frame, Stride, End, Period, Start) ->
    #cal{frame = Frame, sync_frame = Frame, stride = Stride, end_t = End, period = Period, start = Start}.

%% Only every Every-th frame time is a sync point (nobody reads the frames
%% in between).
-spec sparse(calendar(), pos_integer()) -> calendar().
sparse(#cal{frame = F} = Cal, Every) -> Cal#cal{sync_frame = F * Every}.

-spec start(calendar()) -> non_neg_integer().
start(#cal{start = Start}) -> Start.

-spec end_t(calendar()) -> non_neg_integer().
end_t(#cal{end_t = End}) -> End.

-spec period(calendar()) -> non_neg_integer().
period(#cal{period = P}) -> P.

%% Bodies commit at every (sync) frame time and every multiple of the
%% stride, so that GVT can always advance far enough for LVT_ub to reach
%% the next one, and at every regroup point, where groups change once GVT
%% is there.
-spec is_sync(non_neg_integer(), calendar()) -> boolean().
is_sync(T, #cal{sync_frame = F, stride = S, end_t = End, period = P, start = Start}) ->
    T rem F =:= 0 orelse T rem S =:= 0 orelse T =:= End orelse (P > 0 andalso T rem P =:= 0) orelse T =:= Start.

%% The first sync point at or after T (is_sync/2 is true there and at
%% none between T and it; the start, before the start); none past the
%% end.
-spec next_at(non_neg_integer(), calendar()) -> non_neg_integer() | none.
next_at(T, #cal{end_t = End}) when T > End -> none;
next_at(T, #cal{start = Start}) when T =< Start -> Start;
next_at(T, #cal{sync_frame = F, stride = S, end_t = End, period = P}) ->
    %% (called at every sync point a body passes: arithmetic, no lists)
    Frame = (T + F - 1) div F * F,
    Stride = (T + S - 1) div S * S,
    Regroup = case P of
                  0 -> End;
                  _ -> (T + P - 1) div P * P
              end,
    min(min(Frame, Stride), min(Regroup, End)).

%% Frames are written at frame times and at the end only.
-spec is_frame(non_neg_integer(), calendar()) -> boolean().
is_frame(T, #cal{frame = F, end_t = End}) -> T rem F =:= 0 orelse T =:= End.

%% The frame times between T, a sync point, and the sync point before
%% it: frames that are no sync points (none unless sparse/2). GVT passes
%% them when it passes T.
-spec frames_before(non_neg_integer(), calendar()) -> [non_neg_integer()].
frames_before(_T, #cal{frame = F, sync_frame = F}) -> [];
frames_before(T, #cal{start = Start}) when T =< Start -> [];
frames_before(T, #cal{frame = F} = Cal) ->
    lists:seq((last_before(T - 1, Cal) div F + 1) * F, T - 1, F).

%% The first frame time after T that is a sync point.
-spec sync_frame_after(integer(), calendar()) -> non_neg_integer().
sync_frame_after(T, #cal{sync_frame = F}) -> (T div F + 1) * F.

%% The first sync point after G (G before the start: the start). GVT
%% cannot pass it before every body has reached it.
-spec after_gvt(integer(), calendar()) -> non_neg_integer().
after_gvt(G, #cal{start = Start}) when G < Start -> Start;
after_gvt(G, #cal{end_t = End}) when G >= End -> End;
after_gvt(G, Cal) -> next_at(G + 1, Cal).

%% The last sync point at or before T, the end aside.
-spec last_before(non_neg_integer(), calendar()) -> non_neg_integer().
last_before(T, #cal{sync_frame = F, stride = S, period = P, start = Start}) ->
    max(max(T div F * F, T div S * S), max(case P of 0 -> 0; _ -> T div P * P end, min(T, Start))).
