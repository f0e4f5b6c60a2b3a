%% Integration of one sphere over one substep, from its post-response
%% velocities and the pseudo-velocity of penetration removal.
-module(rw_integrate).
-include("rw_physics.hrl").
-export([advance/5, free_displacement/2, integrators/0]).
-export_type([integrator/0]).

-type integrator() :: symplectic_euler | verlet | explicit_euler.
-include("rw_vec_inline.hrl").

-spec integrators() -> [integrator()].
integrators() -> [symplectic_euler, verlet, explicit_euler].

%% State at the next substep. V and W are post-response velocities at this
%% substep, U the pseudo-velocity (zero when nothing penetrates).
-spec advance(#model{}, #st{}, rw_vec:vec(), rw_vec:vec() | undefined, rw_vec:vec()) -> #st{}.
advance(#model{dt = Dt, gravity = G, integrator = Int, rotation = Rot}, #st{p = P, q = Q}, V, W, U) ->
    Vu = add_nonzero(V, U),
    {P1, V1} = case G of
                   undefined ->
                       {vmadd(P, Vu, Dt), V};
                   _ ->
                       V1g = vmadd(V, G, Dt),
                       case Int of
                           symplectic_euler -> {vmadd(P, add_nonzero(V1g, U), Dt), V1g};
                           explicit_euler -> {vmadd(P, Vu, Dt), V1g};
                           verlet -> {vmadd(vmadd(P, Vu, Dt), G, 0.5 * Dt * Dt), V1g}
                       end
               end,
    case Rot of
        true -> #st{p = P1, v = V1, q = rw_quat:integrate(Q, W, Dt), w = W};
        false -> #st{p = P1, v = V1}
    end.

%% How far a body moves over the substep if nothing touches it.
-spec free_displacement(#model{}, #st{}) -> rw_vec:vec().
free_displacement(M, #st{p = P, v = V, w = W} = St) ->
    #st{p = P1} = advance(M, St, V, W, vzero()),
    vsub(P1, P).

%% V + U, or V itself where U is zero (-0.0 too, as a match of 0.0 takes
%% it). Guards rather than a literal {0.0, 0.0, 0.0} in the head: matching
%% a literal tuple calls the runtime's general term comparison.
add_nonzero(V, {UX, UY, UZ}) when UX == 0.0, UY == 0.0, UZ == 0.0 -> V;
add_nonzero(V, U) -> vadd(V, U).
