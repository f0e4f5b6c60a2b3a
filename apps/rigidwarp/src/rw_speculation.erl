%% How far ahead of GVT the bodies of a run may compute (pure): the stride
%% the engine runs with under the run's memory budget for speculation.
%%
%% Every body keeps its states from GVT up to its LVT (its timeline, and
%% the TVHT buckets the same states by reference) until GVT passes them,
%% so the history a run holds grows with bodies x (stride / substep): at
%% a 1 us substep the scenes' 64 ms stride is 64,000 substeps a body, and
%% stack_1000 so took 14 GB before GVT first moved. Where the scene's
%% stride would hold more than the budget, the engine runs with a shorter
%% one (LVT_ub = GVT + that stride); the stride only changes the schedule,
%% never the frames, which stay the reference's bit for bit.
-module(rw_speculation).
-export([stride/4, sync_stride/2, ahead/5, collect_pause/1, budget_bytes/1, default_mb/0, bytes_per_body_substep/0]).

%% The budget when the run does not give one.
-define(DEFAULT_MB, 1024).

%% The memory a run holds per body and per substep of stride, at most
%% where its history is what grows: the growth of the peak of
%% erlang:memory(total) from a stride of 128 substeps to one of 1024 (0.1
%% ms substeps, runs of 600 ms, 2 schedulers, OTP 25) over bodies x 896,
%% Parallel 500 (a free gas, 48-byte states) 510 bytes with the C library
%% and 131 without it, Bouncing 500 (a gas with collisions) 280 and 102,
%% Pile 300 (rotation, 104-byte states) 264 with it; stack_1000 at a 1 us
%% substep and a stride of 2097 substeps held 680 bytes a body-substep in
%% binaries alone as it first stepped. A body keeps up to two strides of
%% history (it prunes once a stride); with the C loops a step also leaves
%% its binaries' garbage behind until the body's next collection, which a
%% body doing little Erlang work seldom has: that grows with the work done
%% rather than with the stride, and the memory guard has it collected
%% (rw_memory_guard).
-define(BYTES_PER_BODY_SUBSTEP, 768).

%% The stride (ticks) that keeps the history of Bodies bodies at substep
%% Dt within Budget bytes: the scene's Stride where it fits, else the
%% longest whole number of substeps that does, and one substep at least
%% (a budget too small for that is not kept).
-spec stride(pos_integer(), non_neg_integer(), pos_integer(), pos_integer()) -> pos_integer().
stride(Budget, Bodies, Dt, Stride) ->
    Substeps = Budget div (max(1, Bodies) * ?BYTES_PER_BODY_SUBSTEP),
    max(Dt, min(Stride, Substeps * Dt)).

%% Sync points fall at every multiple of this (ticks) besides the frame
%% times: the stride, but 512 substeps at most. The memory guard can hold
%% bodies back only as far as the first sync point after GVT (the bodies
%% there must reach it), and GVT frees history only there; the scenes'
%% strides are 64 to 512 substeps, a stride of 64,000 (a 1 us substep)
%% would leave the guard no say.
-define(SYNC_SUBSTEPS, 512).
-spec sync_stride(pos_integer(), pos_integer()) -> pos_integer().
sync_stride(Stride, Dt) -> min(Stride, ?SYNC_SUBSTEPS * Dt).

%% The memory guard's decision (rw_memory_guard) when the run holds Used
%% bytes more than at its start and bodies may step Ahead ticks past GVT:
%% how far they may step from now on, and whether the simulation's
%% processes are to collect their garbage. Over the budget, half as far
%% (a whole number of substeps, one at least) and collect; over three
%% quarters of it, collect; under half of it, twice as far, up to the
%% stride; in between, as far as before.
-spec ahead(integer(), pos_integer(), pos_integer(), pos_integer(), pos_integer()) -> {pos_integer(), boolean()}.
ahead(Used, Budget, Ahead, _Stride, Dt) when Used > Budget -> {max(Dt, Ahead div 2 div Dt * Dt), true};
ahead(Used, Budget, Ahead, _Stride, _Dt) when 4 * Used > 3 * Budget -> {Ahead, true};
ahead(Used, Budget, Ahead, Stride, _Dt) when 2 * Used < Budget -> {min(Stride, 2 * Ahead), false};
ahead(_Used, _Budget, Ahead, _Stride, _Dt) -> {Ahead, false}.

%% How long (ms) the memory guard waits before it asks for collections
%% again, after a round that took RoundMs from its request to the last
%% answer: twice as long, so that rounds take a third of the time at most
%% (a round over the 1064 processes of stack_1000 took 30-80 ms, one over
%% 20,000 takes longer: a run whose memory is not garbage would otherwise
%% spend its time collecting).
-spec collect_pause(non_neg_integer()) -> non_neg_integer().
collect_pause(RoundMs) -> 2 * RoundMs.

%% The budget in bytes of a run's options (speculation_mb, MiB).
-spec budget_bytes(#{speculation_mb => pos_integer(), atom() => term()}) -> pos_integer().
budget_bytes(Opts) -> maps:get(speculation_mb, Opts, ?DEFAULT_MB) bsl 20.

-spec default_mb() -> pos_integer().
default_mb() -> ?DEFAULT_MB.

-spec bytes_per_body_substep() -> pos_integer().
bytes_per_body_substep() -> ?BYTES_PER_BODY_SUBSTEP.
