%% Backpressure on the frames of a run (pure): how far GVT may go while
%% the run's subscribers have frames in hand that they have not handled.
%%
%% The run (rw_run) delivers every frame, or its time, to its subscribers
%% as GVT passes it. Each subscriber that hears of frames has a backlog:
%% the messages of frames delivered to it that it has not handled yet. The
%% run gives GVT an allowance, a frame time: GVT passes no sync point once
%% it has reached the allowance (rw_gvt), so a subscriber is never more
%% than a window of frames behind, and frames wait in the engine's records
%% instead of piling up in a mailbox. The window is counted in frames but
%% bounded in bytes: a frame of many bodies is large.
%%
%% The allowance only moves when it can move by half a window at least, so
%% that GVT hears of it once every half window and not once a frame.
-module(rw_flow).
-export([window/2, allowance/4, move/4, unbounded/0, held/2]).
-export_type([allowance/0]).

%% A frame time in ticks, or unbounded/0.
-type allowance() :: integer().

%% The most bytes of frames a window may hold in one subscriber's
%% mailbox, at the heaviest a body takes in a frame term (its id and four
%% vectors, one of them a quaternion: about 500 bytes on a heap).
-define(BUDGET_BYTES, (64 bsl 20)).
-define(BYTES_PER_BODY, 512).
-define(FEWEST_FRAMES, 2).
-define(MOST_FRAMES, 64).

%% An allowance GVT never reaches: nobody is waited for. (Kept where the
%% GVT process and the watchdog read it, a signed 64-bit atomic.)
-spec unbounded() -> allowance().
unbounded() -> 16#7FFFFFFFFFFFFFFF.

%% The window, in frames, for subscribers of frames of Bodies bodies (a
%% 20,000-sphere frame is some 10 MB: 6 frames) or of times only.
-spec window(non_neg_integer(), frames | times) -> pos_integer().
window(_Bodies, times) -> ?MOST_FRAMES;
window(Bodies, frames) -> max(?FEWEST_FRAMES, min(?MOST_FRAMES, ?BUDGET_BYTES div (max(1, Bodies) * ?BYTES_PER_BODY))).

%% The frame time GVT may reach: Delivered (the latest frame delivered,
%% in ticks) plus the window less the largest backlog, in frames of Frame
%% ticks. Without backlogs to bound (no subscriber of frames or times), no
%% bound.
-spec allowance(integer(), [non_neg_integer()], pos_integer(), pos_integer()) -> allowance().
allowance(_Delivered, [], _Window, _Frame) -> unbounded();
allowance(Delivered, Backlogs, Window, Frame) -> Delivered + (Window - lists:max(Backlogs)) * Frame.

%% Whether the allowance moves from Old to New: when it can go half a
%% window further, or when its bound comes or goes (a subscriber of frames
%% came or the last one left). Once given, an allowance is never taken
%% back otherwise: GVT may have passed it already.
-spec move(allowance(), allowance(), pos_integer(), pos_integer()) -> boolean().
move(Old, Old, _Window, _Frame) -> false;
move(Old, New, Window, Frame) ->
    Old =:= unbounded() orelse New =:= unbounded() orelse New >= Old + max(1, Window div 2) * Frame.

%% GVT at G stays there: it has reached the allowance.
-spec held(integer(), allowance()) -> boolean().
held(G, Allowance) -> G >= Allowance.
