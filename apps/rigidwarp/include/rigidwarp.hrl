-include_lib("rw_physics/include/rw_physics.hrl").

%% A validated scene, ready to run. Bodies are ranked by id: a sphere's or
%% fixture's idx is its position in the sorted list of all ids, and contacts
%% are always summed in that order.
%%
%% Times inside the engines are integer ticks. A tick is 1 ms, as in the
%% paper, unless the scene's times need a finer one (a 0.5 ms substep): then
%% it is the largest whole number of microseconds that divides 1 ms and
%% every time of the scene (rw_scene:ms/2 converts). Users see
%% milliseconds only.
-record(scene, {
    name :: binary(),
    file :: string() | undefined,
    duration :: pos_integer(),            % ticks
    substep :: pos_integer(),             % ticks
    stride :: pos_integer(),              % ticks
    frame :: pos_integer(),               % ticks
    model :: #model{},
    spheres :: [#sphere{}],          % ascending idx
    initial :: [#st{}],              % parallel to spheres, at time start
    start = 0 :: non_neg_integer(),       % ticks: 0, or the checkpoint a run resumes from
    fixtures :: [#fixture{}],        % ascending idx
    cell_size :: float(),
    buckets :: pos_integer() | undefined,
    tick_us = 1000 :: pos_integer()       % microseconds per tick, divides 1000
}).

%% What every process of one Time Warp simulation shares: built once by
%% rw_sim:new/5 before any process of the simulation starts (the GVT
%% process's pid excepted, which the processes started after it get). Its
%% tables, atomics and counters are those of one node: sent to another
%% node it goes without them (rw_sim:portable/1), and the site there puts
%% in its own (rw_sim:for_site/4).
-record(sim, {
    scene :: #scene{},                        % its stride the one the engine runs with (rw_sim:new/5)
    n :: non_neg_integer(),                   % dynamic bodies (of this node's site, on several nodes)
    end_t :: non_neg_integer(),               % ticks
    sync :: rw_sync:calendar(),               % sync points, regroup points
    buckets :: tuple(),                       % bucket pids, index 0 at element 1
    %% which bucket holds a cell: a pool of this many on one node, or a
    %% placement over several (rw_place)
    placement :: pos_integer() | rw_place:placement(),
    gvt :: pid() | undefined,
    records :: ets:tid() | undefined,         % committed states (rw_commits)
    counts :: ets:tid() | undefined,          % bodies committed per sync point (rw_commits)
    ring :: ets:tid() | undefined,            % committed frames (rw_ring)
    owners :: ets:tid() | undefined,          % {Idx, Pid}: the entity that steps body Idx
    procs :: ets:tid() | undefined,           % {Idx, Pid}: the process of body Idx
    met :: ets:tid() | undefined,             % {{A, B}, T}: A met B at many substeps (rw_neighbour)
    stats :: rw_stats:counters() | undefined,
    profile = false :: boolean(),             % count the engine's stages (rw_stats)
    lvts :: atomics:atomics_ref() | undefined,   % every body's LVT, at rw_sim:lvt_slot(Idx)
    %% GVT (slot 1), which bodies read when they step, the next
    %% checkpoint's sync point (slot 2, 0 for none: rw_commits:commit/4),
    %% and how far past GVT bodies may step (rw_sim:ahead_slot/0)
    gvt_now :: atomics:atomics_ref() | undefined,
    %% the records bodies commit (rw_commits:commit/4): whole ones, when
    %% someone reads this run's frames; else, where the regroup plan reads
    %% every body's, slim ones (its motion) but whole ones at the announced
    %% checkpoint's sync point and at the end; else only where the engine
    %% reads them (sparse)
    records_kept = whole :: whole | slim | sparse,
    %% contact groups (rw_regroup): the most bodies in one group, and how
    %% groups are planned (eager: tests only)
    group_max = 1 :: pos_integer(),
    grouping = persistent :: persistent | eager,
    delay = none :: none | {Seed :: integer(), MaxMs :: non_neg_integer()},  % test hook (rw_body)
    %% the engine's C loops, where their library is loaded (rw_native:use/1)
    native = true :: boolean(),
    trace :: ets:tid() | undefined            % tasks recorded for rw_parallelism (rw_trace)
}).

%% Wall time (ms) between checkpoints, by default: how much work a fault or
%% an interruption can cost at most.
-define(CHECKPOINT_MS, 500).
