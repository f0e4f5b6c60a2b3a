%% The committed states of one simulation, in two shared ETS tables: each
%% body's record at each sync point it has committed (record/0, ordered
%% by time, then idx) and, per sync point, how many bodies have
%% committed it ({T, Count, Withdrawals}). An entity commits a sync point once nothing it awaits is
%% about an earlier time, and withdraws it when it rolls back; the commit
%% that completes a sync point tells the GVT process, which checks the
%% count again before it passes it (a rollback may have taken commits
%% back meanwhile).
-module(rw_commits).
-include("rigidwarp.hrl").
-export([record/8, unpack/1, motions_at/3, commit/4, keep/2, checkpoint_at/2, withdraw/3, complete/2, count/2, records_at/2, forget_through/2, forget/2, select_at/2, states_at/2, delete_at/2, keep_only/2]).
-export_type([record/0]).

%% A body's committed state at a sync point, keyed by time and idx: its id
%% and its frame record with its pre-response velocities (v, w). Without
%% rotation they are packed into a heap binary of 49 or 73 bytes (record/8;
%% floats as IEEE doubles, bit for bit): a table of tens of thousands of
%% bodies' records takes one per body and frame, and a flat binary is
%% copied in and out of it at a fraction of the cost of a tree of boxed
%% floats. With rotation the floats would not fit a heap binary (64 bytes
%% at most): packing them cost more than it saved (Cylinders 500 used 6 %
%% more CPU), and they stay tuples.
-type record() :: {{non_neg_integer(), non_neg_integer()}, binary(),
                   binary() | {rw_vec:vec(), rw_vec:vec(), rw_quat:quat(), rw_vec:vec(), rw_vec:vec(), rw_vec:vec()}}.

%% A packed record's velocities after the responses differ from those
%% before.
-define(RESPONDED, 1).
%% A slim record: the position and post-response velocity only, what the
%% regroup plan reads (motions_at/3), packed as a whole record without
%% rotation packs them.
-define(SLIM, 2).

%% The record of body Idx (id Id) at sync point T: position P, velocities
%% V and W after the responses at T, orientation Q, velocities V0 and W0
%% before them (W, Q and W0 undefined without rotation).
-spec record(non_neg_integer(), non_neg_integer(), binary(), rw_vec:vec(), rw_vec:vec(),
             rw_quat:quat() | undefined, rw_vec:vec() | undefined, {rw_vec:vec(), rw_vec:vec() | undefined}) -> record().
record(T, Idx, Id, {PX, PY, PZ}, {VX, VY, VZ} = V, undefined, undefined, {{AX, AY, AZ} = V0, undefined}) ->
    Bin = case same(V, V0) of
              true -> <<0, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float>>;
              false -> <<?RESPONDED, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float,
                         AX:64/float, AY:64/float, AZ:64/float>>
          end,
    {{T, Idx}, Id, Bin};
record(T, Idx, Id, P, V, Q, W, {V0, W0}) ->
    {{T, Idx}, Id, {P, V, Q, W, V0, W0}}.

%% Bit for bit the same vector. =:= and a match take -0.0 for 0.0, so a
%% zero is compared by its bits; floats that are =:= and not zero have the
%% same bits (there is no NaN).
same({X, Y, Z}, {X1, Y1, Z1}) ->
    same_float(X, X1) andalso same_float(Y, Y1) andalso same_float(Z, Z1).

same_float(A, B) when A =:= B, A =/= 0.0 -> true;
same_float(A, B) when A =:= B -> <<A:64/float>> =:= <<B:64/float>>;
same_float(_, _) -> false.

%% The frame record and the pre-response velocities a record holds.
-spec unpack(record()) -> {rw_reference:body_frame(), {rw_vec:vec(), rw_vec:vec() | undefined}}.
unpack({_, Id, {P, V, Q, W, V0, W0}}) -> {{Id, P, V, Q, W}, {V0, W0}};
unpack({_, Id, <<Flags, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float, Pre/binary>>}) ->
    P = {PX, PY, PZ},
    V = {VX, VY, VZ},
    case {Flags, Pre} of
        {0, <<>>} -> {{Id, P, V, undefined, undefined}, {V, undefined}};
        {?RESPONDED, <<AX:64/float, AY:64/float, AZ:64/float>>} -> {{Id, P, V, undefined, undefined}, {{AX, AY, AZ}, undefined}}
    end.

%% Commit the records of an entity's members at sync point T. When nobody
%% reads the frames (#sim.records_kept) they are whole only at the end and
%% at the next checkpoint's sync point (checkpoint_at/2): elsewhere, with
%% sparse records, they are kept only where the regroup plan may read them
%% (Planned, as the entity knows: rw_entity), and slim ones are kept where
%% it reads every body's. Inserting every body's record at every sync point
%% into the ordered table, and deleting it again, is a good part of a
%% gas's work (doc/performance.md).
-spec commit(#sim{}, non_neg_integer(), [record()], boolean()) -> ok.
commit(#sim{records = Records, counts = Counts, n = N, gvt = Gvt} = Sim, T, Rows, Planned) ->
    _ = case Sim#sim.records_kept of
            whole -> ets:insert(Records, Rows);
            slim -> ets:insert(Records, case is_whole(Sim, T) of
                                            true -> Rows;
                                            false -> [slim(Row) || Row <- Rows]
                                        end);
            sparse -> (Planned orelse is_whole(Sim, T)) andalso ets:insert(Records, Rows)
        end,
    case ets:update_counter(Counts, T, {2, length(Rows)}, {T, 0, 0}) of
        N -> rw_trace:send(Gvt, {complete, T});
        _ -> ok
    end.

%% Whole records at T when nobody reads the frames: at the end and at the
%% announced checkpoint's sync point.
is_whole(#sim{end_t = End}, End) -> true;
is_whole(#sim{gvt_now = Now}, T) -> atomics:get(Now, 2) =:= T.

slim({Key, Id, <<_, Motion:48/binary, _/binary>>}) -> {Key, Id, <<?SLIM, Motion/binary>>};
slim({Key, Id, {{PX, PY, PZ}, {VX, VY, VZ}, _Q, _W, _V0, _W0}}) ->
    {Key, Id, <<?SLIM, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float>>}.

%% Keep the records of an entity's members at sync point T, committed
%% before: the regroup plan is to read them after all.
-spec keep(#sim{}, [record()]) -> ok.
keep(#sim{records = Records}, Rows) ->
    true = ets:insert(Records, Rows),
    ok.

%% With sparse records, the sync point T of the next checkpoint, whose
%% records every body keeps: announced once no body can have committed it
%% yet (past LVT_ub).
-spec checkpoint_at(#sim{}, non_neg_integer()) -> ok.
checkpoint_at(#sim{gvt_now = Now}, T) -> atomics:put(Now, 2, T).

%% Take back the commits of members Idxs at the sync points Times.
-spec withdraw(#sim{}, [non_neg_integer()], [non_neg_integer()]) -> ok.
withdraw(#sim{records = Records, counts = Counts}, Times, Idxs) ->
    N = length(Idxs),
    lists:foreach(fun(T) ->
                          _ = ets:update_counter(Counts, T, [{2, -N}, {3, 1}]),
                          lists:foreach(fun(Idx) -> true = ets:delete(Records, {T, Idx}) end, Idxs)
                  end, Times).

%% Has every body committed sync point T?
-spec complete(#sim{}, non_neg_integer()) -> boolean().
complete(#sim{counts = Counts, n = N}, T) ->
    case ets:lookup(Counts, T) of
        [{_, N, _}] -> true;
        _ -> false
    end.

%% How many bodies have committed sync point T, and how many withdrawals
%% of T there have been: a count that is whole twice with the same
%% withdrawals was whole all along in between (rw_gvt_site).
-spec count(#sim{}, non_neg_integer()) -> {non_neg_integer(), non_neg_integer()}.
count(#sim{counts = Counts}, T) ->
    case ets:lookup(Counts, T) of
        [{_, C, W}] -> {C, W};
        [] -> {0, 0}
    end.

%% Every record committed at sync point T (the site of a simulation on
%% several nodes sends them to the node that assembles the frames).
-spec records_at(non_neg_integer(), ets:tid()) -> [record()].
records_at(T, Records) -> ets:select(Records, [{{{T, '_'}, '_', '_'}, [], ['$_']}]).

%% GVT has passed T: its count is no longer needed.
-spec forget(#sim{}, non_neg_integer()) -> ok.
forget(#sim{counts = Counts}, T) ->
    true = ets:delete(Counts, T),
    ok.

%% The records committed at sync point T, in idx order: one per body once
%% GVT has passed T, unless they are slim (none is then a frame).
-spec select_at(non_neg_integer(), ets:tid()) -> [rw_reference:body_frame()].
select_at(T, Records) -> [element(1, unpack(R)) || R <- records_at(T, Records), not is_slim(R)].

is_slim({_, _, <<?SLIM, _/binary>>}) -> true;
is_slim(_) -> false.

%% The positions and post-response velocities of the bodies Idxs (all:
%% every body) at sync point T, once GVT has passed T: {Idx, P, V} in idx
%% order.
-spec motions_at(non_neg_integer(), all | [non_neg_integer()], ets:tid()) -> [{non_neg_integer(), rw_vec:vec(), rw_vec:vec()}].
motions_at(T, all, Records) ->
    %% (a record with rotation holds six vectors: only two are copied out
    %% of the table, for the GVT process, which every body waits for)
    [motion(R) || R <- ets:select(Records, [{{{T, '$1'}, '_', {'$2', '$3', '_', '_', '_', '_'}}, [], [{{'$1', '$2', '$3'}}]},
                                            {{{T, '_'}, '_', '$1'}, [{is_binary, '$1'}], ['$_']}])];
motions_at(T, Idxs, Records) -> [motion(R) || Idx <- Idxs, R <- ets:lookup(Records, {T, Idx})].

motion({{_, Idx}, _, <<_, PX:64/float, PY:64/float, PZ:64/float, VX:64/float, VY:64/float, VZ:64/float, _/binary>>}) ->
    {Idx, {PX, PY, PZ}, {VX, VY, VZ}};
motion({{_, Idx}, _, {P, V, _, _, _, _}}) -> {Idx, P, V};
motion({Idx, _, _} = Motion) when is_integer(Idx) -> Motion.

%% Every body's whole pre-response state at sync point T, in idx order
%% (once GVT has passed T): what a run resumed from T starts with.
-spec states_at(non_neg_integer(), ets:tid()) -> [#st{}].
states_at(T, Records) ->
    [#st{p = P, v = V, q = Q, w = W} || R <- records_at(T, Records), {{_, P, _, Q, _}, {V, W}} <- [unpack(R)]].

%% GVT has passed G: forget the counts and records of every sync point up
%% to G.
-spec forget_through(#sim{}, non_neg_integer()) -> ok.
forget_through(#sim{counts = Counts, records = Records}, G) ->
    _ = ets:select_delete(Counts, [{{'$1', '_', '_'}, [{'=<', '$1', G}], [true]}]),
    delete_through(G, Records, ets:first(Records)).

delete_through(G, Records, {T, _}) when T =< G ->
    ok = delete_at(T, Records),
    delete_through(G, Records, ets:next(Records, {T, later}));
delete_through(_G, _Records, _) -> ok.

%% Forget the records of sync point T.
-spec delete_at(non_neg_integer(), ets:tid()) -> ok.
delete_at(T, Records) ->
    _ = ets:select_delete(Records, [{{{T, '_'}, '_', '_'}, [], [true]}]),
    ok.

%% Forget the records of every time but Keep (ticks): after a fault, only
%% the frames of the ring are known to be whole and committed.
-spec keep_only(ets:tid(), [non_neg_integer()]) -> ok.
keep_only(Records, Keep) -> keep_only(Records, ets:first(Records), maps:from_keys(Keep, true)).

keep_only(_Records, '$end_of_table', _Keep) -> ok;
keep_only(Records, {T, _}, Keep) ->
    _ = case Keep of
            #{T := _} -> ok;
            #{} -> delete_at(T, Records)
        end,
    %% an atom sorts after every idx: the first key of the next time
    keep_only(Records, ets:next(Records, {T, later}), Keep).
