%% The counters of one Time Warp simulation: the only place that knows
%% their names and slots. Entities, buckets and the GVT process bump them
%% (a `counters` array with write concurrency: no process in the way);
%% stats/1 of rw_timewarp reads them by name.
%%
%% The *_reductions counters are kept only when a simulation is profiled
%% (the `profile` option): work done per stage of the engine, in
%% reductions, the VM's unit of work, which preemption does not inflate as
%% it does wall time.
-module(rw_stats).
-export([new/0, add/3, read/2, timed/3]).
-export_type([name/0, counters/0]).

-type name() :: events | antievents | primary_rollbacks | secondary_rollbacks | rolled_back_substeps
              | computed_substeps | steps | regroups | memory_holds
              | tvht_reductions | integrate_reductions | rollback_reductions | gvt_reductions.
-type counters() :: counters:counters_ref().

%% steps: writes to the TVHT (one per step of an entity, any length);
%% regroups: contact groups that change; memory_holds: times the memory
%% guard cut how far bodies step past GVT (rw_memory_guard).
names() ->
    [events, antievents, primary_rollbacks, secondary_rollbacks, rolled_back_substeps, computed_substeps,
     steps, regroups, memory_holds | profile_names()].

%% tvht: hashing by the entities, the rest by the buckets; rollback: an
%% entity's own bookkeeping of a rollback (the buckets count their deletes
%% as TVHT work); gvt: commits, the GVT process and history pruning.
profile_names() -> [tvht_reductions, integrate_reductions, rollback_reductions, gvt_reductions].

-spec new() -> counters().
new() -> counters:new(length(names()), [write_concurrency]).

-spec add(counters(), name(), integer()) -> ok.
add(Ref, Name, N) -> counters:add(Ref, slot(Name), N).

slot(events) -> 1;
slot(antievents) -> 2;
slot(primary_rollbacks) -> 3;
slot(secondary_rollbacks) -> 4;
slot(rolled_back_substeps) -> 5;
slot(computed_substeps) -> 6;
slot(steps) -> 7;
slot(regroups) -> 8;
slot(tvht_reductions) -> 9;
slot(integrate_reductions) -> 10;
slot(rollback_reductions) -> 11;
slot(gvt_reductions) -> 12;
slot(memory_holds) -> 13.

%% Every counter by name (the profile's only when Profile).
-spec read(counters(), boolean()) -> #{name() => integer()}.
read(Ref, Profile) ->
    Names = case Profile of
                true -> names();
                false -> names() -- profile_names()
            end,
    maps:from_list([{N, counters:get(Ref, slot(N))} || N <- Names]).

%% Fun(), its reductions counted into Stage.
-spec timed(counters(), name(), fun(() -> T)) -> T.
timed(Ref, Stage, Fun) ->
    R0 = reductions(),
    Result = Fun(),
    add(Ref, Stage, reductions() - R0),
    Result.

%% Work done by the calling process so far.
reductions() -> element(2, erlang:process_info(self(), reductions)).
