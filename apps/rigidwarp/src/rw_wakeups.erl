%% The entities waiting for GVT to reach some time (pure): a GVT process
%% (rw_gvt on one node, rw_gvt_site on each of several) wakes them when it
%% passes it. A few distinct times, each with up to every body: a list per
%% time, ascending, where a set of {At, Pid} would hold an element per body.
-module(rw_wakeups).
-export([new/0, add/3, wake/2]).
-export_type([wakeups/0]).

-type wakeups() :: [{integer(), [pid()]}].

-spec new() -> wakeups().
new() -> [].

%% Pid waits for GVT At.
-spec add(integer(), pid(), wakeups()) -> wakeups().
add(At, Pid, [{A, _} = First | Rest]) when A < At -> [First | add(At, Pid, Rest)];
add(At, Pid, [{At, Pids} | Rest]) -> [{At, [Pid | Pids]} | Rest];
add(At, Pid, Later) -> [{At, [Pid]} | Later].

%% GVT is G: send {gvt, G} to every entity waiting for G or earlier; the
%% others still wait.
-spec wake(integer(), wakeups()) -> wakeups().
wake(G, [{At, Pids} | Rest]) when At =< G ->
    _ = [rw_trace:send(Pid, {gvt, G}) || Pid <- Pids],
    wake(G, Rest);
wake(_G, Waiting) -> Waiting.
