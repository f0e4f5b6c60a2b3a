%% The entities waiting for GVT to reach some time (pure): a GVT process
%% (rw_gvt on one node, rw_gvt_site on each of several) wakes them when it
%% passes it. Each time with the entities waiting for it, in a tree by
%% time: tens of thousands of bodies wait for hundreds of distinct times.
-module(rw_wakeups).
-export([new/0, add/3, wake/2]).
-export_type([wakeups/0]).

-opaque wakeups() :: gb_trees:tree(integer(), [pid()]).

-spec new() -> wakeups().
new() -> gb_trees:empty().

%% Pid waits for GVT At.
-spec add(integer(), pid(), wakeups()) -> wakeups().
add(At, Pid, W) ->
    case gb_trees:lookup(At, W) of
        {value, Pids} -> gb_trees:update(At, [Pid | Pids], W);
        none -> gb_trees:insert(At, [Pid], W)
    end.

%% GVT is G: send {gvt, G} to every entity waiting for G or earlier (the
%% earliest times first); the others still wait.
-spec wake(integer(), wakeups()) -> wakeups().
wake(G, W) ->
    case gb_trees:is_empty(W) orelse gb_trees:smallest(W) of
        {At, Pids} when At =< G ->
            _ = [rw_trace:send(Pid, {gvt, G}) || Pid <- Pids],
            wake(G, gb_trees:delete(At, W));
        _ -> W
    end.
