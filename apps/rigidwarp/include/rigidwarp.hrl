-include_lib("rw_physics/include/rw_physics.hrl").

%% A validated scene, ready to run. Bodies are ranked by id: a sphere's or
%% fixture's idx is its position in the sorted list of all ids, and contacts
%% are always summed in that order.
-record(scene, {
    name :: binary(),
    file :: string() | undefined,
    duration_ms :: pos_integer(),
    substep_ms :: pos_integer(),
    stride_ms :: pos_integer(),
    frame_ms :: pos_integer(),
    model :: #model{},
    spheres :: [#sphere{}],          % ascending idx
    initial :: [#st{}],              % parallel to spheres
    fixtures :: [#fixture{}],        % ascending idx
    cell_size :: float(),
    buckets :: pos_integer() | undefined
}).

%% What every process of one Time Warp simulation shares: set once at start.
-record(sim, {
    scene :: #scene{},
    n :: pos_integer(),                       % dynamic bodies
    end_ms :: non_neg_integer(),
    buckets :: tuple(),                       % bucket pids, index 0 at element 1
    gvt :: pid() | undefined,
    records :: ets:tid(),                     % {{T, Idx}, BodyFrame}: committed states
    counts :: ets:tid(),                      % {T, Committed}: bodies committed at T
    ring :: ets:tid(),                        % committed frames (see rw_gvt)
    stats :: counters:counters_ref(),         % see rw_timewarp:stat_index/1
    profile = false :: boolean(),             % time the engine's stages (rw_timewarp:stats/1)
    lvts :: atomics:atomics_ref(),            % every body's LVT, at rw_timewarp:lvt_slot(Idx)
    gvt_now :: atomics:atomics_ref()          % GVT (slot 1), which bodies read when they step
}).
