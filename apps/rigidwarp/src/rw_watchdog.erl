%% The watchdog of one simulation: if GVT does not advance for a while
%% before the end, it tells the simulation's run (rw_run, which logs it and
%% restarts the simulation from its latest checkpoint) a diagnosis
%% naming every body's phase, LVT and awaited acknowledgements, the bodies
%% holding GVT back first ({rw_stalled, GvtPid, GvtMs, Report}); then it
%% stops watching. It reads GVT where the entities do (#sim.gvt_now) and
%% asks nothing of the GVT process. GVT held at the allowance (rw_flow)
%% waits for the run's subscribers, not for a body: no stall.
-module(rw_watchdog).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/4]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-record(w, {
    sim :: #sim{},
    owner :: pid() | undefined,
    ms :: pos_integer(),
    flow :: atomics:atomics_ref() | undefined,   % the allowance (rw_flow)
    gvt = -1 :: integer(),            % GVT at the last look
    since :: integer()                % when it last changed (monotonic ms)
}).

-spec start_link(#sim{}, pid() | undefined, pos_integer(), atomics:atomics_ref() | undefined) -> {ok, pid()}.
start_link(Sim, Owner, Ms, Flow) -> gen_server:start_link(?MODULE, {Sim, Owner, Ms, Flow}, []).

-spec init({#sim{}, pid() | undefined, pos_integer(), atomics:atomics_ref() | undefined}) -> {ok, #w{}}.
init({Sim, Owner, Ms, Flow}) ->
    _ = erlang:send_after(Ms div 4 + 1, self(), look),
    {ok, #w{sim = Sim, owner = Owner, ms = Ms, flow = Flow, since = now_ms()}}.

-spec handle_call(term(), gen_server:from(), #w{}) -> {reply, ok, #w{}}.
handle_call(_Req, _From, W) -> {reply, ok, W}.

-spec handle_cast(term(), #w{}) -> {noreply, #w{}}.
handle_cast(_Msg, W) -> {noreply, W}.

-spec handle_info(term(), #w{}) -> {noreply, #w{}}.
handle_info(look, #w{sim = #sim{gvt_now = Now, end_t = End} = Sim, gvt = Last, since = Since, ms = Ms} = W) ->
    case atomics:get(Now, 1) of
        End ->
            {noreply, W};
        Last ->
            case {flow_held(Last, W), now_ms() - Since > Ms} of
                {true, _} ->
                    %% the time held does not count
                    _ = erlang:send_after(Ms div 4 + 1, self(), look),
                    {noreply, W#w{since = now_ms()}};
                {false, true} ->
                    Report = diagnose(Sim),
                    GvtMs = rw_scene:ms(Sim#sim.scene, Last),
                    _ = [Pid ! {rw_stalled, Sim#sim.gvt, GvtMs, Report} || Pid <- [W#w.owner], is_pid(Pid)],
                    {noreply, W};
                {false, false} ->
                    _ = erlang:send_after(Ms div 4 + 1, self(), look),
                    {noreply, W}
            end;
        G ->
            _ = erlang:send_after(Ms div 4 + 1, self(), look),
            {noreply, W#w{gvt = G, since = now_ms()}}
    end;
handle_info(_Msg, W) ->
    {noreply, W}.

flow_held(_G, #w{flow = undefined}) -> false;
flow_held(G, #w{flow = Flow}) -> rw_flow:held(G, atomics:get(Flow, 1)).

%% Who waits on whom: each body's phase, LVT, what it awaits and how many
%% messages it has not read yet, the bodies holding GVT back first.
diagnose(#sim{procs = Procs}) ->
    Lines = [describe(B) || {_, B} <- lists:sort(ets:tab2list(Procs))],
    lists:flatten(["bodies by LVT, lowest (holding GVT back) first:\n"
                   | [[L, $\n] || {_, L} <- lists:keysort(1, Lines)]]).

%% A body described on its own node: its state holds that node's tables
%% and atomics, which are not to leave it.
describe(B) when node(B) =:= node() -> describe_here(B);
describe(B) ->
    try erpc:call(node(B), fun() -> describe_here(B) end, 2000)
    catch
        _:Reason -> {-1, io_lib:format("~p: cannot be asked (~0P)", [B, Reason, 6])}
    end.

describe_here(B) ->
    try sys:get_state(B, 500) of
        {_Phase, D} -> rw_body:describe(D, unread(B))
    catch
        exit:_ -> {-1, io_lib:format("~p: not answering (blocked in a bucket call?); ~ts", [B, queue(B)])}
    end.

unread(Pid) ->
    case erlang:process_info(Pid, message_queue_len) of
        {message_queue_len, N} -> N;
        undefined -> 0
    end.

queue(Pid) ->
    case erlang:process_info(Pid, message_queue_len) of
        {message_queue_len, N} -> io_lib:format("~b unread messages", [N]);
        undefined -> "dead"
    end.

now_ms() -> erlang:monotonic_time(millisecond).
