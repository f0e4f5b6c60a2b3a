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
    initial :: [#st{}],              % parallel to spheres
    fixtures :: [#fixture{}],        % ascending idx
    cell_size :: float(),
    buckets :: pos_integer() | undefined,
    tick_us = 1000 :: pos_integer()       % microseconds per tick, divides 1000
}).

%% What every process of one Time Warp simulation shares: set once at start.
-record(sim, {
    scene :: #scene{},
    n :: pos_integer(),                       % dynamic bodies
    end_t :: non_neg_integer(),                % ticks
    buckets :: tuple(),                       % bucket pids, index 0 at element 1
    gvt :: pid() | undefined,
    records :: ets:tid(),                     % {{T, Idx}, BodyFrame}: committed states
    counts :: ets:tid(),                      % {T, Committed}: bodies committed at T
    ring :: ets:tid(),                        % committed frames (see rw_gvt)
    stats :: counters:counters_ref(),         % see rw_timewarp:stat_index/1
    profile = false :: boolean(),             % time the engine's stages (rw_timewarp:stats/1)
    lvts :: atomics:atomics_ref(),            % every body's LVT, at rw_timewarp:lvt_slot(Idx)
    gvt_now :: atomics:atomics_ref(),         % GVT (slot 1), which bodies read when they step
    %% contact groups (rw_regroup): bodies may regroup at every multiple of
    %% period (0: each body stays on its own), planned a period earlier
    period = 0 :: non_neg_integer(),          % ticks
    group_max = 1 :: pos_integer(),           % the most bodies in one group
    grouping = persistent :: persistent | eager,   % eager: tests only
    plans :: ets:tid(),                       % {{S, Idx}, rw_regroup:move()}: what body Idx does at S
    met :: ets:tid(),                         % {{A, B}, T}: A met B at many substeps (rw_body:touch/5)
    owners :: ets:tid()                       % {Idx, Pid}: the entity that steps body Idx
}).
