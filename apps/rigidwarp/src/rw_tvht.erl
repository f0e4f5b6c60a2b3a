%% The client side of the TVHT: an entity's write of one step and its
%% delete of the states after a rollback point, carried out on the buckets
%% of the plan (rw_tvht_plan) in bucket order, under their locks (Lemma 1).
%% No lock is held while waiting for anything but another bucket's lock.
-module(rw_tvht).
-export([write/4, delete/5]).

%% Probe the buckets of the plan in order under their locks, store the
%% states up to the first LVT with contacts (or Last), and unlock:
%% {UpTo, Hits (one per member and partner), contact ids, where it went}.
-spec write(tuple(), rw_cells:write(), rw_tvht_plan:plan(), non_neg_integer()) ->
          {non_neg_integer(), [rw_cells:hit()], rw_cells:ids(), rw_tvht_plan:where()}.
write(Buckets, Write, [{B, Cells, Spans}], Last) ->
    {UpTo, Hits, Ids} = rw_bucket:probe_commit(element(B + 1, Buckets), Cells, Write, Spans, Last),
    {UpTo, Hits, Ids, [{B, Cells}]};
write(Buckets, {Writer, _, _, _} = Write, Plan, Last) ->
    Results = [rw_bucket:lock_probe(element(B + 1, Buckets), Cells, rw_tvht_plan:for_bucket(Write, Spans), Spans)
               || {B, Cells, Spans} <- Plan],
    {UpTo, Hits} = rw_tvht_plan:first_contacts(Results, Last),
    Pairs = [{I, element(1, E)} || {I, E, _} <- Hits],
    Ids = rw_cells:contact_ids(UpTo, Pairs, [make_ref() || _ <- Pairs]),
    _ = [rw_bucket:commit_unlock(element(B + 1, Buckets), Writer, UpTo, Ids) || {B, _, _} <- Plan],
    {UpTo, Hits, Ids, [{B, Cells} || {B, Cells, _} <- Plan]}.

%% Delete Owner's states after R (of its members Idxs) from where they
%% went, and return the contacts they had: [{Cid, Detector, Other}].
-spec delete(tuple(), pid(), rw_tvht_plan:where(), [non_neg_integer()], non_neg_integer()) ->
          [{rw_cells:cid(), pid(), pid()}].
delete(Buckets, Owner, Where, Idxs, R) ->
    Plan = rw_tvht_plan:delete(Where),
    Lost = lists:append([rw_bucket:lock_delete(element(B + 1, Buckets), Owner, Cells, Idxs, R) || {B, Cells} <- Plan]),
    _ = [rw_bucket:unlock(element(B + 1, Buckets), Owner) || {B, _} <- Plan],
    Lost.
