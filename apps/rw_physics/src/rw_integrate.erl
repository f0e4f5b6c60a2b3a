%% Integration of one sphere over one substep, from its post-response
%% velocities and the pseudo-velocity of penetration removal.
-module(rw_integrate).
-include("rw_physics.hrl").
-export([advance/5, move/10, free_displacement/2, integrators/0]).
-export_type([integrator/0]).

-type integrator() :: symplectic_euler | verlet | explicit_euler.
-include("rw_vec_inline.hrl").

-spec integrators() -> [integrator()].
integrators() -> [symplectic_euler, verlet, explicit_euler].

%% State at the next substep. V and W are post-response velocities at this
%% substep, U the pseudo-velocity (zero when nothing penetrates).
-spec advance(#model{}, #st{}, rw_vec:vec(), rw_vec:vec() | undefined, rw_vec:vec()) -> #st{}.
advance(#model{dt = Dt, rotation = Rot} = M, #st{p = {X, Y, Z}, q = Q}, {VX, VY, VZ}, W, {UX, UY, UZ}) ->
    {X1, Y1, Z1, VX1, VY1, VZ1} = move(M, X, Y, Z, VX, VY, VZ, UX, UY, UZ),
    case Rot of
        true -> #st{p = {X1, Y1, Z1}, v = {VX1, VY1, VZ1}, q = rw_quat:integrate(Q, W, Dt), w = W};
        false -> #st{p = {X1, Y1, Z1}, v = {VX1, VY1, VZ1}}
    end.

%% advance/5's position and velocity, coordinate by coordinate: from
%% {X, Y, Z} with post-response velocity {VX, VY, VZ} and pseudo-velocity
%% {UX, UY, UZ} (zero, -0.0 too, when nothing penetrates). The engine's
%% free flight (rw_chain) calls it with a zero pseudo-velocity on the
%% coordinates it keeps apart.
-spec move(#model{}, float(), float(), float(), float(), float(), float(), float(), float(), float()) ->
          {float(), float(), float(), float(), float(), float()}.
move(#model{dt = Dt, gravity = G, integrator = Int}, X, Y, Z, VX, VY, VZ, UX, UY, UZ)
  when is_float(X), is_float(Y), is_float(Z), is_float(VX), is_float(VY), is_float(VZ), is_float(UX), is_float(UY),
       is_float(UZ), is_float(Dt) ->
    Free = UX == 0.0 andalso UY == 0.0 andalso UZ == 0.0,
    case G of
        undefined ->
            {X + plus(VX, UX, Free) * Dt, Y + plus(VY, UY, Free) * Dt, Z + plus(VZ, UZ, Free) * Dt, VX, VY, VZ};
        {GX, GY, GZ} when is_float(GX), is_float(GY), is_float(GZ) ->
            VXg = VX + GX * Dt,
            VYg = VY + GY * Dt,
            VZg = VZ + GZ * Dt,
            case Int of
                symplectic_euler ->
                    {X + plus(VXg, UX, Free) * Dt, Y + plus(VYg, UY, Free) * Dt, Z + plus(VZg, UZ, Free) * Dt,
                     VXg, VYg, VZg};
                explicit_euler ->
                    {X + plus(VX, UX, Free) * Dt, Y + plus(VY, UY, Free) * Dt, Z + plus(VZ, UZ, Free) * Dt,
                     VXg, VYg, VZg};
                verlet ->
                    H = 0.5 * Dt * Dt,
                    {(X + plus(VX, UX, Free) * Dt) + GX * H, (Y + plus(VY, UY, Free) * Dt) + GY * H,
                     (Z + plus(VZ, UZ, Free) * Dt) + GZ * H, VXg, VYg, VZg}
            end
    end.

%% How far a body moves over the substep if nothing touches it.
-spec free_displacement(#model{}, #st{}) -> rw_vec:vec().
free_displacement(M, #st{p = P, v = V, w = W} = St) ->
    #st{p = P1} = advance(M, St, V, W, vzero()),
    vsub(P1, P).

%% V + U, or V itself where the pseudo-velocity is zero.
-compile({inline, [plus/3]}).
plus(V, _U, true) -> V;
plus(V, U, false) -> V + U.
