%% The context of one Time Warp simulation (#sim{}, rigidwarp.hrl): built
%% once from the scene, the options, the simulation's tables and its
%% bucket pool, and handed to every process of the simulation as a start
%% argument.
-module(rw_sim).
-include("rigidwarp.hrl").
-export([new/5, portable/1, for_site/4, for_bodies/1, lvt_slot/1, ahead_slot/0, lead/4]).
-export_type([options/0, tables/0, lead/0]).

%% The simulation's working tables (rw_sim_tables) and the run's records
%% and ring (rw_run).
-type tables() :: #{records := ets:tid(), ring := ets:tid(), counts := ets:tid(), owners := ets:tid(),
                    procs := ets:tid(), met := ets:tid()}.

-type options() :: #{groups => boolean(), group_max => pos_integer(), native => boolean(),
                     %% (tests) regroup points this many strides apart, groups of
                     %% all bodies near each other however they move
                     regroup_every => pos_integer(), grouping => persistent | eager,
                     profile => boolean(), delay => {Seed :: integer(), MaxMs :: non_neg_integer()},
                     read_frames => boolean(),
                     %% the memory the run's speculative history may take (rw_speculation)
                     speculation_mb => pos_integer(),
                     trace => ets:tid(),
                     atom() => term()}.

%% The most bodies the engine steps as one contact group, by default: a
%% group is one process, and groups should remain many enough to keep every
%% scheduler busy.
-define(DEFAULT_GROUP_MAX, 1024).
%% The LVT of a body on another node, as this node's bodies read it.
-define(NOT_HERE, 16#FFFFFFFFFFFFFFFF).

%% The context's scene is the one the engine runs: its stride is the
%% scene's, or shorter where the scene's would take more memory than the
%% run's budget for speculation (rw_speculation).
-spec new(#scene{}, tables(), tuple(), rw_stats:counters(), options()) -> #sim{}.
new(#scene{spheres = Spheres, duration = End, frame = Frame, stride = Asked, start = Start, substep = Dt} = Scene0,
    #{records := Records, counts := Counts, ring := Ring, owners := Owners, procs := Procs, met := Met},
    Buckets, Stats, Opts) ->
    Stride = rw_speculation:stride(rw_speculation:budget_bytes(Opts), length(Spheres), Dt, Asked),
    Scene = Scene0#scene{stride = Stride},
    Kept = records_kept(Scene, Opts),
    SyncEvery = sync_every(Kept =:= sparse, Scene),
    Period = case {maps:get(groups, Opts, true), maps:find(regroup_every, Opts)} of
                 {false, _} -> 0;
                 {true, {ok, Every}} -> Every * Stride;
                 {true, error} -> period(Dt, Frame * SyncEvery)
             end,
    Cal = rw_sync:sparse(rw_sync:new(Frame, rw_speculation:sync_stride(Stride, Dt), End, Period, Start), SyncEvery),
    #sim{scene = Scene, n = length(Spheres), end_t = End, sync = Cal,
         buckets = Buckets, placement = tuple_size(Buckets), records = Records, counts = Counts, ring = Ring, owners = Owners, procs = Procs,
         met = Met, stats = Stats, profile = maps:get(profile, Opts, false),
         lvts = lvts(Spheres, Start),
         gvt_now = gvt_now(Stride), group_max = maps:get(group_max, Opts, ?DEFAULT_GROUP_MAX),
         grouping = maps:get(grouping, Opts, persistent), delay = maps:get(delay, Opts, none),
         trace = maps:get(trace, Opts, undefined),
         native = maps:get(native, Opts, rw_native:default()),
         records_kept = Kept}.

%% Records only where the engine reads them when nobody reads the frames,
%% on one node, and the regroup plan reads the records of group members
%% and of bodies that met only; slim ones where it reads every body's
%% motion (as rw_gvt plans: landing under gravity). A whole record with
%% rotation is a tuple of six vectors, copied into the ordered table and
%% out again: Cylinders 500 ran 1.05 times as fast with slim ones.
records_kept(#scene{model = #model{gravity = Gravity}}, Opts) ->
    case maps:get(read_frames, Opts, true) of
        true -> whole;
        false ->
            case rw_regroup:reads_only_some(maps:get(grouping, Opts, persistent), Gravity =/= undefined) of
                true -> sparse;
                false -> slim
            end
    end.

%% Every how many frame times a sync point falls. Where nobody reads the
%% frames (sparse records) they need not be sync points, only times the
%% run hears of: some two sync points a stride instead of one a frame,
%% and regroup points as far apart. A body flying a whole stride alone
%% commits at each (Parallel 500 ran 1.4 times as fast with frame times
%% every 120 ms instead of 10, Bouncing 500 as fast).
sync_every(false, _Scene) -> 1;
sync_every(true, #scene{frame = F, stride = S}) -> max(1, S div (2 * F)).

%% Every body's LVT, at its start time until it publishes another.
lvts(Spheres, Start) ->
    Lvts = atomics:new(lvt_slot(lists:max([0 | [I || #sphere{idx = I} <- Spheres]])), [{signed, false}]),
    _ = [atomics:put(Lvts, lvt_slot(I), Start) || Start > 0, #sphere{idx = I} <- Spheres],
    Lvts.

%% The context without what belongs to this node (ETS tables, atomics,
%% counters): what is sent to the sites on other nodes.
-spec portable(#sim{}) -> #sim{}.
portable(Sim) ->
    Sim#sim{records = undefined, counts = undefined, ring = undefined, owners = undefined, procs = undefined,
            met = undefined, stats = undefined, lvts = undefined, gvt_now = undefined}.

%% The context of one node's share of a simulation over several nodes: its
%% own bodies (Idxs), tables, counters and GVT process. Only the LVTs of the
%% bodies here are published here: the others read as never limiting (the
%% neighbour rule changes only the schedule, and a contact group is never
%% split over nodes).
-spec for_site(#sim{}, [non_neg_integer()], tables(), rw_stats:counters()) -> #sim{}.
for_site(#sim{scene = #scene{spheres = Spheres, start = Start}} = Sim, Idxs,
         #{records := Records, counts := Counts, owners := Owners, procs := Procs, met := Met}, Stats) ->
    Lvts = lvts(Spheres, Start),
    Here = maps:from_keys(Idxs, true),
    _ = [atomics:put(Lvts, lvt_slot(I), ?NOT_HERE) || #sphere{idx = I} <- Spheres, not is_map_key(I, Here)],
    Sim#sim{n = length(Idxs), records = Records, counts = Counts, owners = Owners, procs = Procs, met = Met,
            stats = Stats, lvts = Lvts, gvt_now = gvt_now(Sim#sim.scene#scene.stride)}.

%% What a body holds: not the whole scene's bodies, which it never reads
%% (a copy per body fills the heaps).
-spec for_bodies(#sim{}) -> #sim{}.
for_bodies(#sim{scene = Scene} = Sim) -> Sim#sim{scene = Scene#scene{spheres = [], initial = []}}.

%% Where body Idx publishes its LVT in #sim.lvts: one 64-byte cache line
%% per body, so that bodies on different cores do not share lines.
-spec lvt_slot(non_neg_integer()) -> pos_integer().
lvt_slot(Idx) -> Idx * 8 + 1.

%% The highest LVT published by the bodies Idxs (all: every slot), as read
%% at monotonic ms At: {At, Lead}, or none before the first read.
-type lead() :: none | {integer(), non_neg_integer()}.

%% The highest LVT of the bodies Idxs at Now (monotonic ms), read anew only
%% when the last read is a millisecond old per 20 bodies (a second at
%% 20,000): a read goes over every body's slot, some 60-120 ns a body, while
%% the stats that show it are read many times a second (a progress line at
%% every frame, a bench's samples), so the reads take at most a few
%% thousandths of a core.
-spec lead(atomics:atomics_ref(), all | [non_neg_integer()], integer(), lead()) -> {non_neg_integer(), lead()}.
lead(Lvts, Idxs, Now, Last) ->
    Bodies = case Idxs of
                 all -> (maps:get(size, atomics:info(Lvts)) - 1) div 8 + 1;
                 _ -> length(Idxs)
             end,
    case Last of
        {At, Lead} when Now - At < Bodies div 20 -> {Lead, Last};
        _ -> fresh(Now, read(Lvts, Idxs))
    end.

read(Lvts, all) ->
    #{size := Size} = atomics:info(Lvts),
    [atomics:get(Lvts, I) || I <- lists:seq(1, Size, 8)];
read(Lvts, Idxs) ->
    [atomics:get(Lvts, lvt_slot(I)) || I <- Idxs].

fresh(Now, Lvts) ->
    Lead = lists:max([0 | Lvts]),
    {Lead, {Now, Lead}}.

%% Where in #sim.gvt_now bodies read how far past GVT they may step (the
%% stride, unless the run's memory guard holds them back: rw_memory_guard).
-spec ahead_slot() -> pos_integer().
ahead_slot() -> 3.

gvt_now(Stride) ->
    Ref = atomics:new(3, [{signed, true}]),
    ok = atomics:put(Ref, 1, -1),
    ok = atomics:put(Ref, ahead_slot(), Stride),
    Ref.

%% Bodies may regroup at the frame times that are sync points (every F
%% ticks), at least 8 substeps apart (every frame in the paper's scenes:
%% 10 ms), planned when GVT reaches the regroup point before (rw_gvt): a
%% new persistent contact is stepped as one group one or two periods after
%% its bodies have met often enough to say so. Those frame times are sync
%% points anyway; regroup points of their own would add a commit per body
%% at each, a cost even to scenes that never regroup.
period(Dt, F) -> F * max(1, (8 * Dt + F - 1) div F).
