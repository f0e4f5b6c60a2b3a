%% The neighbour rule (pure): an entity in persistent contact with an
%% outside body goes at most one substep past that body's entity. Beyond
%% that it could not see their next contact, and would be rolled back when
%% the other one finds it. The entity with the lowest LVT is never held, so
%% some entity can always move.
%%
%% A partner counts as in persistent contact for a few substeps after its
%% second touch within as many substeps: a single touch is most often a
%% bounce, after which the two fly apart, and holding both to one substep
%% per write for the next few substeps would multiply their writes (most
%% one substep long) without sparing a rollback. Touches are
%% remembered by partner (the latest two substeps); one undone by a
%% rollback may hold the entity back a little longer than needed, never
%% less.
%%
%% The same touches say which pairs meet often enough to be worth one
%% contact group (rw_regroup): every ?MET substeps of touching are reported.
-module(rw_neighbour).
-export([new/0, touch/4, partners/3, limit/2, forget/3]).
-export_type([touched/0]).

-define(RECENT_SUBSTEPS, 8).
%% A bounce in a gas of spheres lasts one to three substeps, so 4 substeps
%% of touching mean a lasting contact: fewer would group bouncing spheres
%% and regroup them over and over, more would group resting bodies later.
-define(MET, 4).

%% Per outside body: the latest two substeps at which a member touched it
%% (the earlier one none after a single touch), and at how many substeps it
%% has touched it since it was last reported.
-type touched() :: #{non_neg_integer() => {non_neg_integer(), non_neg_integer() | none, non_neg_integer()}}.

-spec new() -> touched().
new() -> #{}.

%% Member Idx touches the outside body PIdx at T; a pair that has touched
%% at ?MET substeps is reported as {Lower, Higher, T}.
-spec touch(non_neg_integer(), non_neg_integer(), non_neg_integer(), touched()) ->
          {touched(), none | {non_neg_integer(), non_neg_integer(), non_neg_integer()}}.
touch(Idx, PIdx, T, Touched) ->
    case Touched of
        #{PIdx := {Last, _, _}} when Last >= T -> {Touched, none};
        #{PIdx := {Last, _, N}} when N + 1 >= ?MET -> {Touched#{PIdx := {T, Last, 0}}, {min(Idx, PIdx), max(Idx, PIdx), T}};
        #{PIdx := {Last, _, N}} -> {Touched#{PIdx := {T, Last, N + 1}}, none};
        _ -> {Touched#{PIdx => {T, none, 1}}, none}
    end.

%% The outside bodies in persistent contact with an entity at Lvt: those
%% whose LVT limits it.
-spec partners(non_neg_integer(), pos_integer(), touched()) -> [non_neg_integer()].
partners(_Lvt, _Dt, Touched) when map_size(Touched) =:= 0 -> [];
partners(Lvt, Dt, Touched) ->
    Since = Lvt - ?RECENT_SUBSTEPS * Dt,
    [PIdx || {PIdx, {T, Before, _}} <- maps:to_list(Touched), T > Since, is_integer(Before),
             Before >= T - ?RECENT_SUBSTEPS * Dt].

%% {Limit, Idx}: how far the slowest of the partners (their LVTs) lets the
%% entity go (its LVT plus one substep), the lowest idx on a tie; or none.
-spec limit([{non_neg_integer(), non_neg_integer()}], pos_integer()) -> none | {non_neg_integer(), non_neg_integer()}.
limit([], _Dt) -> none;
limit(Lvts, Dt) -> lists:min([{Lvt + Dt, PIdx} || {PIdx, Lvt} <- Lvts]).

%% Forget the touches too old to matter to an entity at GVT G or later.
-spec forget(non_neg_integer(), pos_integer(), touched()) -> touched().
forget(G, Dt, Touched) ->
    Since = G - ?RECENT_SUBSTEPS * Dt,
    maps:filter(fun(_, {T, _, _}) -> T > Since end, Touched).
