%% How well this machine itself scales from 1 to N schedulers on work like
%% the engine's, without the engine: processes building and dropping small
%% lists and maps, the allocation and garbage collection that dominate the
%% bodies and buckets. The host is shared and what two cores give over one
%% changes by the minute, so the engine's speedups are read against this
%% (`rigidwarp bench machine`, scripts/paper-scenes, Fig. 7 of make bench).
-module(rw_machine).
-export([parallel_ms/2, scaling/1, median/1]).

%% Wall ms for Procs processes, each doing the same fixed work, on
%% Schedulers schedulers (the schedulers online are put back after).
-spec parallel_ms(pos_integer(), pos_integer()) -> non_neg_integer().
parallel_ms(Schedulers, Procs) ->
    Old = erlang:system_flag(schedulers_online, min(Schedulers, erlang:system_info(schedulers))),
    try
        Self = self(),
        T0 = erlang:monotonic_time(microsecond),
        Pids = [spawn_link(fun() -> Self ! {self(), churn(1000000, #{})} end) || _ <- lists:seq(1, Procs)],
        [receive {Pid, _} -> ok end || Pid <- Pids],
        (erlang:monotonic_time(microsecond) - T0) div 1000
    after
        erlang:system_flag(schedulers_online, Old)
    end.

%% Repeats pairs of two processes on 1 and then on 2 schedulers: every
%% pair's times, and the median and range of their ratios.
-spec scaling(pos_integer()) -> #{atom() => term()}.
scaling(Repeats) ->
    Pairs = [{parallel_ms(1, 2), parallel_ms(2, 2)} || _ <- lists:seq(1, Repeats)],
    Ratios = [A / max(B, 1) || {A, B} <- Pairs],
    #{one_scheduler_ms => [A || {A, _} <- Pairs], two_schedulers_ms => [B || {_, B} <- Pairs],
      scaling => median(Ratios), scaling_min => lists:min(Ratios), scaling_max => lists:max(Ratios),
      schedulers => erlang:system_info(schedulers)}.

churn(0, M) -> map_size(M);
churn(N, M) -> churn(N - 1, M#{N band 63 => lists:seq(1, 8)}).

%% The middle value, or the mean of the middle two (every bench's median).
-spec median([number(), ...]) -> number().
median(Xs) ->
    S = lists:sort(Xs),
    N = length(S),
    case N rem 2 of
        1 -> lists:nth(N div 2 + 1, S);
        0 -> (lists:nth(N div 2, S) + lists:nth(N div 2 + 1, S)) / 2
    end.
