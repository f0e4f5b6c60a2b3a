%% The memory guard of one simulation on one node: it keeps what the run
%% holds within its budget where the stride chosen for it
%% (rw_speculation:stride/4) is not enough: rollbacks in a long window
%% keep the states of the writes they cut short, a pile keeps its
%% contacts of every substep, and bodies leave their steps' garbage until
%% their next collection.
%%
%% Now and then it reads how much more memory the VM holds than when the
%% simulation's processes had all started, and rw_speculation:ahead/5
%% decides how far past GVT bodies may step (the atomics slot they read
%% with GVT, rw_sim:ahead_slot/0) and whether the simulation's processes
%% are asked to collect their garbage: once they have all done so since
%% the last time, and after a pause twice as long as that took
%% (rw_speculation:collect_pause/1). A body never stops short of the first sync point after
%% GVT (rw_entity), so the run goes on however far the guard holds it
%% back. Every cut counts as a memory hold (rw_stats).
%%
%% The memory it reads is the whole VM's: another run in the same VM
%% counts against this one's budget.
-module(rw_memory_guard).
-behaviour(gen_server).
-include("rigidwarp.hrl").
-export([start_link/3]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

%% Between two looks: a read of the VM's memory takes 0.1 ms, and up to
%% 15 ms while the schedulers are busy, so twice a second while the run
%% holds less than a quarter of its budget (Parallel 500 used 3 % more
%% CPU with ten looks a second), ten times a second above.
-define(LOOK_MS, 100).
-define(IDLE_LOOK_MS, 500).

-record(g, {
    sim :: #sim{},
    pids :: [pid()],                      % the processes asked to collect
    budget :: pos_integer(),              % bytes
    base :: non_neg_integer(),            % erlang:memory(total) at the start
    %% collections asked for and not yet done, and when they were asked
    %% for (monotonic ms); when the next round may be asked for
    collecting = 0 :: non_neg_integer(),
    asked :: integer(),
    next :: integer()
}).

-spec start_link(#sim{}, [pid()], pos_integer()) -> {ok, pid()}.
start_link(Sim, Pids, Budget) -> gen_server:start_link(?MODULE, {Sim, Pids, Budget}, []).

-spec init({#sim{}, [pid()], pos_integer()}) -> {ok, #g{}}.
init({Sim, Pids, Budget}) ->
    %% (at normal priority, its looks waited behind every runnable body:
    %% a second and more as a thousand bodies took their first steps)
    _ = process_flag(priority, high),
    _ = erlang:send_after(?LOOK_MS, self(), look),
    {ok, #g{sim = Sim, pids = Pids, budget = Budget, base = erlang:memory(total), asked = now_ms(), next = now_ms()}}.

-spec handle_call(term(), gen_server:from(), #g{}) -> {reply, ok, #g{}}.
handle_call(_Req, _From, G) -> {reply, ok, G}.

-spec handle_cast(term(), #g{}) -> {noreply, #g{}}.
handle_cast(_Msg, G) -> {noreply, G}.

-spec handle_info(term(), #g{}) -> {noreply, #g{}}.
handle_info(look, #g{sim = #sim{gvt_now = Now, scene = #scene{stride = Stride, substep = Dt}, stats = Stats},
                     budget = Budget, base = Base} = G) ->
    Used = erlang:memory(total) - Base,
    _ = erlang:send_after(case 4 * Used < Budget of true -> ?IDLE_LOOK_MS; false -> ?LOOK_MS end, self(), look),
    Ahead = atomics:get(Now, rw_sim:ahead_slot()),
    {Ahead1, Collect} = rw_speculation:ahead(Used, Budget, Ahead, Stride, Dt),
    ok = atomics:put(Now, rw_sim:ahead_slot(), Ahead1),
    _ = Ahead1 < Ahead andalso rw_stats:add(Stats, memory_holds, 1),
    {noreply, case Collect of
                  true -> collect(G);
                  false -> G
              end};
handle_info({garbage_collect, ?MODULE, _}, #g{collecting = 1, asked = Asked} = G) ->
    Now = now_ms(),
    {noreply, G#g{collecting = 0, next = Now + rw_speculation:collect_pause(Now - Asked)}};
handle_info({garbage_collect, ?MODULE, _}, #g{collecting = N} = G) ->
    {noreply, G#g{collecting = N - 1}};
handle_info(_Msg, G) ->
    {noreply, G}.

%% Ask every process of the simulation to collect its garbage (a body's
%% dead binaries are most of it), unless the last round is still being
%% carried out or its pause has not passed.
collect(#g{collecting = 0, pids = Pids, next = Next} = G) ->
    Now = now_ms(),
    case Now >= Next of
        true ->
            _ = [erlang:garbage_collect(P, [{async, ?MODULE}]) || P <- Pids],
            G#g{collecting = length(Pids), asked = Now};
        false ->
            G
    end;
collect(G) -> G.

now_ms() -> erlang:monotonic_time(millisecond).
