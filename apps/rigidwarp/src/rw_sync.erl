%% The sync calendar of a Time Warp simulation (pure): the times at which
%% every entity commits its state and GVT may stop. Sync points are the
%% frame times, the multiples of the stride, the regroup points (multiples
%% of the period, when contact groups are on) and the end time. GVT
%% advances from one sync point to the next once every body has committed
%% it; a body that waits for GVT asks to be woken at a sync point.
-module(rw_sync).
-export([new/4, new/5, start/1, is_sync/2, next_at/2, is_frame/2, frame_after/2, after_gvt/2, last_before/2, end_t/1, period/1]).
-export_type([calendar/0]).

-record(cal, {
    frame :: pos_integer(),          % ticks
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
    #cal{frame = Frame, stride = Stride, end_t = End, period = Period, start = Start}.

-spec start(calendar()) -> non_neg_integer().
start(#cal{start = Start}) -> Start.

-spec end_t(calendar()) -> non_neg_integer().
end_t(#cal{end_t = End}) -> End.

-spec period(calendar()) -> non_neg_integer().
period(#cal{period = P}) -> P.

%% Bodies commit at every frame time and every multiple of the stride, so
%% that GVT can always advance far enough for LVT_ub to reach the next one,
%% and at every regroup point, where groups change once GVT is there.
-spec is_sync(non_neg_integer(), calendar()) -> boolean().
is_sync(T, #cal{frame = F, stride = S, end_t = End, period = P}) ->
    T rem F =:= 0 orelse T rem S =:= 0 orelse T =:= End orelse (P > 0 andalso T rem P =:= 0).

%% The first sync point at or after T (is_sync/2 is true there and at
%% none between T and it); none past the end.
-spec next_at(non_neg_integer(), calendar()) -> non_neg_integer() | none.
next_at(T, #cal{end_t = End}) when T > End -> none;
next_at(T, #cal{frame = F, stride = S, end_t = End, period = P}) ->
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

%% The first frame time after T.
-spec frame_after(integer(), calendar()) -> non_neg_integer().
frame_after(T, #cal{frame = F}) -> (T div F + 1) * F.

%% The first sync point after G (G before the start: the start). GVT
%% cannot pass it before every body has reached it.
-spec after_gvt(integer(), calendar()) -> non_neg_integer().
after_gvt(G, #cal{start = Start}) when G < Start -> Start;
after_gvt(G, #cal{end_t = End}) when G >= End -> End;
after_gvt(G, Cal) -> next_at(G + 1, Cal).

%% The last frame time, multiple of the stride or regroup point at or
%% before T.
-spec last_before(non_neg_integer(), calendar()) -> non_neg_integer().
last_before(T, #cal{frame = F, stride = S, period = P}) ->
    max(max(T div F * F, T div S * S), case P of 0 -> 0; _ -> T div P * P end).
