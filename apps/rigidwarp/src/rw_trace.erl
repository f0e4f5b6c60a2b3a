%% A run's work as tasks with their dependencies, for the parallelism
%% projection (rw_parallelism): when a simulation is traced (option trace,
%% an ETS table of the caller's), every handling of one message by a body,
%% a bucket or the GVT process is a task, with its cost in reductions, the
%% messages it took in and sent, and the sync points it committed; the
%% time it spent in the C loops (rw_native), which count few reductions,
%% is added at the rate of the engine's Erlang code. A body
%% waiting for a bucket's answer ends its task there and begins another
%% when the answer comes, so the bucket's work (and its waiting for a lock)
%% lies between the two.
%%
%% A message is known at both ends by its receiver and a hash of its term
%% (key/2): the sender records it sent, the receiver that it took it in,
%% and rw_parallelism joins them, each taken-in message to the last one
%% sent before it under the same key.
%%
%% The tracer's state is in the process dictionary of each traced process
%% (as logger's metadata is): tracing is the exception, and the engine's
%% code paths stay the same without it. Without a table, every call here
%% does nothing.
-module(rw_trace).
-export([init/1, table/0, task/3, begin_task/2, end_task/0, send/2, sent/2, received/1, committed/1, key/2,
         timing/0, native_begin/0, native_end/1]).
-export_type([task/0, key/0]).

-define(TAB, '$rw_trace_tab').
-define(TASK, '$rw_trace_task').
%% the time in the C loops so far in the task and the reductions they
%% counted (their share of the time slice, which they report), and when
%% the current call began
-define(NATIVE, '$rw_trace_native').
-define(NATIVE_REDS, '$rw_trace_native_reds').
-define(NATIVE_START, '$rw_trace_native_start').
%% Reductions per microsecond of the engine's Erlang code (17-32 over whole
%% runs on a 2-core AMD EPYC, OTP 25): the cost of a microsecond in C.
-define(REDUCTIONS_PER_US, 25).

%% A message: its receiver and the hash of its term.
-type key() :: {pid(), non_neg_integer()}.
%% {Seq, Process, Kind, Reductions, TakenIn, Sent, Committed}: Seq orders
%% the tasks as they began (a task begins after every task it depends on).
-type task() :: {pos_integer(), pid(), body | bucket | gvt, non_neg_integer(), [key()], [key()], [non_neg_integer()]}.

%% This process is traced into Tab (undefined: not traced).
-spec init(ets:tid() | undefined) -> ok.
init(undefined) -> ok;
init(Tab) ->
    _ = put(?TAB, Tab),
    ok.

-spec table() -> ets:tid() | undefined.
table() -> get(?TAB).

-spec key(pid(), term()) -> key().
key(To, Msg) -> {To, erlang:phash2(Msg)}.

%% Fun() handling Msg (none: a timeout), as one task when this process is
%% traced.
-spec task(body | bucket | gvt, term(), fun(() -> R)) -> R.
task(Kind, Msg, Fun) ->
    case get(?TAB) of
        undefined -> Fun();
        _ ->
            ok = begin_task(Kind, Msg),
            Result = Fun(),
            ok = end_task(),
            Result
    end.

%% A task of this process begins, taking in Msg (none: a timeout).
-spec begin_task(body | bucket | gvt, term()) -> ok.
begin_task(Kind, Msg) ->
    case get(?TAB) of
        undefined -> ok;
        _ ->
            In = case Msg of
                     none -> [];
                     _ -> [key(self(), Msg)]
                 end,
            {reductions, R} = process_info(self(), reductions),
            _ = put(?TASK, {erlang:unique_integer([monotonic, positive]), Kind, R, In, [], []}),
            _ = put(?NATIVE, 0),
            _ = put(?NATIVE_REDS, 0),
            ok
    end.

%% The task ends: it is recorded.
-spec end_task() -> ok.
end_task() ->
    case get(?TAB) of
        undefined -> ok;
        Tab ->
            case erase(?TASK) of
                undefined -> ok;
                {Seq, Kind, R0, In, Out, Commits} ->
                    {reductions, R} = process_info(self(), reductions),
                    Native = erlang:convert_time_unit(erase(?NATIVE), native, microsecond) * ?REDUCTIONS_PER_US,
                    true = ets:insert(Tab, {Seq, self(), Kind, R - R0 - erase(?NATIVE_REDS) + Native, In, Out, Commits}),
                    ok
            end
    end.

%% Send Msg to To, recorded.
-spec send(pid(), term()) -> ok.
send(To, Msg) ->
    ok = sent(To, Msg),
    To ! Msg,
    ok.

%% Msg is being sent to To (by a function that sends it itself).
-spec sent(pid(), term()) -> ok.
sent(To, Msg) ->
    case get(?TASK) of
        undefined -> ok;
        {Seq, Kind, R0, In, Out, Commits} ->
            _ = put(?TASK, {Seq, Kind, R0, In, [key(To, Msg) | Out], Commits}),
            ok
    end.

%% Msg was taken in by the current task (an answer awaited inside it).
-spec received(term()) -> ok.
received(Msg) ->
    case get(?TASK) of
        undefined -> ok;
        {Seq, Kind, R0, In, Out, Commits} ->
            _ = put(?TASK, {Seq, Kind, R0, [key(self(), Msg) | In], Out, Commits}),
            ok
    end.

%% The current task committed sync point T (the GVT process: advanced GVT
%% to T).
-spec committed(non_neg_integer()) -> ok.
committed(T) ->
    case get(?TASK) of
        undefined -> ok;
        {Seq, Kind, R0, In, Out, Commits} ->
            _ = put(?TASK, {Seq, Kind, R0, In, Out, [T | Commits]}),
            ok
    end.

%% Is a task of this process being traced? Then a C loop's call is timed:
%% native_begin/0 before it, native_end/1 with its result after it.
-spec timing() -> boolean().
timing() -> get(?TASK) =/= undefined.

-spec native_begin() -> ok.
native_begin() ->
    {reductions, R} = process_info(self(), reductions),
    _ = put(?NATIVE_START, {erlang:monotonic_time(), R}),
    ok.

%% (the call's time counts at the rate of Erlang code, in place of the
%% reductions it reported)
-spec native_end(R) -> R.
native_end(Result) ->
    {reductions, R} = process_info(self(), reductions),
    {T0, R0} = get(?NATIVE_START),
    _ = put(?NATIVE, get(?NATIVE) + (erlang:monotonic_time() - T0)),
    _ = put(?NATIVE_REDS, get(?NATIVE_REDS) + (R - R0)),
    Result.
