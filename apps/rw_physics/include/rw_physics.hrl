%% Records shared by the physics core and the engines.

%% What a scene models. Left-out features are `undefined`/`false`, and the
%% physics does no work for them.
-record(model, {
    dt = 0.001 :: float(),                         % substep in seconds
    gravity = undefined :: undefined | rw_vec:vec(),
    restitution = 1.0 :: float(),
    friction = undefined :: undefined | float(),   % Coulomb coefficient
    rotation = false :: boolean(),
    integrator = symplectic_euler :: rw_integrate:integrator(),
    ccd = false :: boolean(),
    rest_speed = 0.0 :: float(),      % approach speeds below this bounce with restitution 0
    correction = 0.4 :: float(),      % share of penetration removed per substep (pseudo-velocity)
    slop = 0.0 :: float()             % penetration depth left alone (m)
}).

%% Time-invariant properties of a dynamic sphere. `idx` is the body's rank
%% in the scene's id order: contacts are summed in that order.
-record(sphere, {
    idx :: non_neg_integer(),
    id :: binary(),
    radius :: float(),
    mass :: float(),
    inv_mass :: float(),
    inv_inertia :: float()            % 1 / (2/5 m r^2)
}).

%% State of a dynamic sphere at one substep, before contact response.
%% q and w are `undefined` when rotation is not modelled.
-record(st, {
    p :: rw_vec:vec(),
    v :: rw_vec:vec(),
    q = undefined :: undefined | rw_quat:quat(),
    w = undefined :: undefined | rw_vec:vec()
}).

%% A static body; never moves, so it is not a process. box bounds a
%% bounded shape, padded against rounding (rw_shape:fixture/3), so that
%% the narrowphase skips a sphere far from it with six comparisons.
-record(fixture, {
    idx :: non_neg_integer(),
    id :: binary(),
    shape :: rw_shape:static_shape(),
    box = unbounded :: rw_shape:box6() | unbounded
}).

%% A contact as the narrowphase reports it: normal from the first body (the
%% lower index, or the sphere against a fixture) to the second, penetration
%% depth (negative for a swept contact that is not touching yet) and the
%% fraction of the substep at which the bodies touch (0.0 when overlapping).
-record(contact, {
    n :: rw_vec:vec(),
    depth :: float(),
    toi = 0.0 :: float()
}).
