%% Integration of one sphere over one substep, from its post-response
%% velocities and the pseudo-velocity of penetration removal.
-module(rw_integrate).
-include("rw_physics.hrl").
-export([advance/5, free_displacement/2, integrators/0]).
-export_type([integrator/0]).

-type integrator() :: symplectic_euler | verlet | explicit_euler.

-spec integrators() -> [integrator()].
integrators() -> [symplectic_euler, verlet, explicit_euler].

%% State at the next substep. V and W are post-response velocities at this
%% substep, U the pseudo-velocity (zero when nothing penetrates).
-spec advance(#model{}, #st{}, rw_vec:vec(), rw_vec:vec() | undefined, rw_vec:vec()) -> #st{}.
advance(#model{dt = Dt, gravity = G, integrator = Int, rotation = Rot}, #st{p = P, q = Q}, V, W, U) ->
    Vu = add_nonzero(V, U),
    {P1, V1} = case G of
                   undefined ->
                       {rw_vec:madd(P, Vu, Dt), V};
                   _ ->
                       V1g = rw_vec:madd(V, G, Dt),
                       case Int of
                           symplectic_euler -> {rw_vec:madd(P, add_nonzero(V1g, U), Dt), V1g};
                           explicit_euler -> {rw_vec:madd(P, Vu, Dt), V1g};
                           verlet -> {rw_vec:madd(rw_vec:madd(P, Vu, Dt), G, 0.5 * Dt * Dt), V1g}
                       end
               end,
    case Rot of
        true -> #st{p = P1, v = V1, q = rw_quat:integrate(Q, W, Dt), w = W};
        false -> #st{p = P1, v = V1}
    end.

%% How far a body moves over the substep if nothing touches it.
-spec free_displacement(#model{}, #st{}) -> rw_vec:vec().
free_displacement(M, #st{p = P, v = V, w = W} = St) ->
    #st{p = P1} = advance(M, St, V, W, rw_vec:zero()),
    rw_vec:sub(P1, P).

add_nonzero(V, {0.0, 0.0, 0.0}) -> V;
add_nonzero(V, U) -> rw_vec:add(V, U).
