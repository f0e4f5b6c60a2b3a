%% An entity's history from GVT to its LVT (pure): what it wrote to the
%% TVHT, the contacts it knows of with bodies outside it, and the sync
%% points it has committed.
%%
%% Writes cover every substep from GVT up to LVT without gaps, newest
%% first; each holds its substeps T0..UpTo, where in the TVHT it went (the
%% TVHT client's business) and each member's pre-response states from T0
%% on, packed in one off-heap binary (rw_states), so that the history costs
%% the garbage collector nothing. Contacts are kept per substep, each as
%% the member's half of the pair's effect; the post-response velocities at
%% a substep are always recomputed from the pre-response states and all
%% their contacts (rw_island), never updated in place.
-module(rw_timeline).
-export([new/0, add_write/5, state_at/3, where_after/2, truncate/2, prune/2,
         contacts_at/2, put_contacts/3, external/2, contact_times/3,
         is_committed/2, commit/2, withdraw/2]).
-export_type([timeline/0, known/0]).

%% A contact with a body outside the entity at some substep: the member it
%% touches, the partner, and the member's half of the pair's effect.
-type known() :: {non_neg_integer(), non_neg_integer(), rw_response:effect()}.

-record(tl, {
    writes = [] :: [{non_neg_integer(), non_neg_integer(), [term()], tuple()}],
    contacts = #{} :: #{non_neg_integer() => #{rw_entity:cid() => known()}},
    committed = [] :: [non_neg_integer()]         % newest first
}).
-opaque timeline() :: #tl{}.

-spec new() -> timeline().
new() -> #tl{}.

%% A write of substeps T0..UpTo: Where it went, and per member (a tuple in
%% member order) its packed states from T0 on.
-spec add_write(non_neg_integer(), non_neg_integer(), [term()], tuple(), timeline()) -> timeline().
add_write(T0, UpTo, Where, Packed, #tl{writes = W} = TL) -> TL#tl{writes = [{T0, UpTo, Where, Packed} | W]}.

%% The members' pre-response states at substep T (GVT =< T =< LVT), as a
%% tuple: in the newest write that starts at or before T.
-spec state_at(non_neg_integer(), pos_integer(), timeline()) -> tuple().
state_at(T, Dt, #tl{writes = W}) -> state_in(T, W, Dt).

state_in(T, [{T0, _, _, Packed} | _], Dt) when T0 =< T ->
    I = (T - T0) div Dt + 1,
    list_to_tuple([rw_states:state(P, I) || P <- tuple_to_list(Packed)]);
state_in(T, [_ | Older], Dt) -> state_in(T, Older, Dt).

%% Where the states after R went (the items of every write holding one).
-spec where_after(non_neg_integer(), timeline()) -> [term()].
where_after(R, #tl{writes = W}) -> [X || {_, UpTo, Ws, _} <- W, UpTo > R, X <- Ws].

%% Back to R: the writes end at R, the contacts after R are gone. (The
%% commits at R and later are taken back by withdraw/2.)
-spec truncate(non_neg_integer(), timeline()) -> timeline().
truncate(R, #tl{writes = W, contacts = C} = TL) ->
    TL#tl{writes = [{T0, min(UpTo, R), Ws, P} || {T0, UpTo, Ws, P} <- W, T0 =< R],
          contacts = maps:filter(fun(T, _) -> T =< R end, C)}.

%% History before GVT G can never be needed again.
-spec prune(non_neg_integer(), timeline()) -> timeline().
prune(G, #tl{writes = W, contacts = C, committed = Committed}) ->
    #tl{writes = [X || {_, UpTo, _, _} = X <- W, UpTo >= G], contacts = maps:filter(fun(T, _) -> T >= G end, C),
        committed = [T || T <- Committed, T > G]}.

%% The contacts known at substep T, by contact id.
-spec contacts_at(non_neg_integer(), timeline()) -> #{rw_entity:cid() => known()}.
contacts_at(T, #tl{contacts = C}) -> maps:get(T, C, #{}).

-spec put_contacts(non_neg_integer(), #{rw_entity:cid() => known()}, timeline()) -> timeline().
put_contacts(T, AtT, #tl{contacts = C} = TL) -> TL#tl{contacts = C#{T => AtT}}.

%% Effects of the contacts with outside bodies at T, by member, as the
%% island takes them.
-spec external(non_neg_integer(), timeline()) -> [rw_island:external()].
external(_T, #tl{contacts = C}) when map_size(C) =:= 0 -> [];
external(T, #tl{contacts = C}) ->
    case C of
        #{T := AtT} -> [{Member, {{Partner, 0}, E}} || {Member, Partner, E} <- maps:values(AtT)];
        _ -> []
    end.

%% The times in [From, To) with known contacts, ascending.
-spec contact_times(non_neg_integer(), non_neg_integer(), timeline()) -> [non_neg_integer()].
contact_times(_From, _To, #tl{contacts = C}) when map_size(C) =:= 0 -> [];
contact_times(From, To, #tl{contacts = C}) ->
    lists:sort([T || {T, AtT} <- maps:to_list(C), T >= From, T < To, map_size(AtT) > 0]).

-spec is_committed(non_neg_integer(), timeline()) -> boolean().
is_committed(T, #tl{committed = C}) -> lists:member(T, C).

-spec commit(non_neg_integer(), timeline()) -> timeline().
commit(T, #tl{committed = C} = TL) -> TL#tl{committed = [T | C]}.

%% Take back every commit at or after T: the times taken back.
-spec withdraw(non_neg_integer(), timeline()) -> {[non_neg_integer()], timeline()}.
withdraw(T, #tl{committed = C} = TL) ->
    {Gone, Kept} = lists:partition(fun(X) -> X >= T end, C),
    {Gone, TL#tl{committed = Kept}}.
