%% Contact response as velocity changes. An impulse changes velocities only;
%% penetration is removed by a pseudo-velocity (split impulse) that moves the
%% next position and is then forgotten, so it never adds kinetic energy and
%% never moves a position that was already computed.
%%
%% A pair is always evaluated in canonical order (lower index first), so the
%% two bodies receive bit-identical halves of the same computation.
-module(rw_response).
-include("rw_physics.hrl").
-export([pair/6, fixture/4]).
-export_type([effect/0]).

%% What one contact does to one body: change of velocity, of angular
%% velocity (undefined without rotation) and pseudo-velocity.
-type effect() :: {Dv :: rw_vec:vec(), Dw :: rw_vec:vec() | undefined, Du :: rw_vec:vec()}.

-define(TINY, 1.0e-12).
-include("rw_vec_inline.hrl").

-spec pair(#model{}, #sphere{}, #st{}, #sphere{}, #st{}, #contact{}) -> {effect(), effect()}.
pair(M, #sphere{inv_mass = ImA, inv_inertia = IiA, radius = RA}, #st{v = VA, w = WA},
     #sphere{inv_mass = ImB, inv_inertia = IiB, radius = RB}, #st{v = VB, w = WB}, Contact) ->
    impulse(M, ImA, IiA, RA, VA, WA, ImB, IiB, RB, VB, WB, Contact).

%% Sphere against a static body: the fixture has infinite mass and no motion.
%% The impulse acts on the velocity the sphere will have after this
%% substep's gravity (as Box2D integrates velocities before solving
%% contacts): a sphere resting on a fixture then gets exactly the impulse
%% that cancels gravity, and does not sink, however long the substep.
%% Between two spheres gravity changes both velocities alike, so pairs
%% need no such term.
-spec fixture(#model{}, #sphere{}, #st{}, #contact{}) -> effect().
fixture(#model{rotation = Rot, gravity = G, dt = Dt} = M, #sphere{inv_mass = Im, inv_inertia = Ii, radius = R},
        #st{v = V, w = W}, #contact{n = N} = Contact) ->
    Vg = case G of
             undefined -> V;
             _ -> vmadd(V, G, Dt)
         end,
    %% the pair impulse with B at rest, of zero radius and inverse mass
    %% (its contact point's velocity is exactly zero), less B's half
    VcA = case Rot of
              true -> vadd(Vg, vcross(W, vscale(N, R)));
              false -> Vg
          end,
    {JA, Ub} = normal_friction(M, vsub(vzero(), VcA), Im + 0.0, R * R * Ii + 0.0, Contact),
    side(JA, arm(Rot, N, JA), Im, R * Ii, Ub, Contact).

impulse(#model{rotation = Rot} = M, ImA, IiA, RA, VA, WA, ImB, IiB, RB, VB, WB, #contact{n = N} = Contact) ->
    %% velocities of the two surface points in contact
    {VcA, VcB} = case Rot of
                     true -> {vadd(VA, vcross(WA, vscale(N, RA))),
                              vadd(VB, vcross(WB, vscale(N, -RB)))};
                     false -> {VA, VB}
                 end,
    {JA, Ub} = normal_friction(M, vsub(VcB, VcA), ImA + ImB, RA * RA * IiA + RB * RB * IiB, Contact),
    %% (B receives the opposite impulse; r x J with r = RA n for A and
    %% r = -RB n, J = -JA for B: the same arm n x JA)
    Arm = arm(Rot, N, JA),
    {side(JA, Arm, ImA, RA * IiA, Ub, Contact), side(JA, Arm, -ImB, RB * IiB, Ub, Contact)}.

%% The impulse on A from the relative velocity of the contact points and
%% the inverse masses K (and KRot of rotation), and the pseudo-impulse
%% that removes penetration (zero when none).
normal_friction(#model{rotation = Rot, restitution = E, rest_speed = RestSpeed, friction = Mu,
                       correction = Beta, slop = Slop, dt = Dt},
                Vrel, K, KRot, #contact{n = N, depth = Depth}) ->
    Vn = vdot(Vrel, N),
    Jn = case Vn < 0.0 of
             true ->
                 Bounce = case -Vn > RestSpeed of true -> E; false -> 0.0 end,
                 -(1.0 + Bounce) * Vn / K;
             false -> 0.0
         end,
    JA = friction(Mu, Rot, Jn, Vrel, Vn, N, K, KRot, vscale(N, -Jn)),
    Pen = Depth - Slop,
    Ub = case Pen > 0.0 of
             true -> Beta * Pen / Dt / K;
             false -> none
         end,
    {JA, Ub}.

%% n x JA with rotation, else undefined.
arm(true, N, JA) -> vcross(N, JA);
arm(false, _N, _JA) -> undefined.

%% One body's effect: impulse JA (on A) scaled by its signed inverse mass
%% Im (negative for B), its angular change from Arm, and its pseudo-velocity
%% against n (-Ub Im, zero when nothing penetrates); a swept contact at
%% fraction Toi moves with the old velocity until then.
side(JA, Arm, Im, ArmScale, Ub, #contact{n = N, toi = Toi}) ->
    Dv = vscale(JA, Im),
    Dw = case Arm of
             undefined -> undefined;
             _ -> vscale(Arm, ArmScale)
         end,
    U = case Ub of
            none -> vzero();
            _ -> vscale(N, -Ub * Im)
        end,
    Du = case Toi > 0.0 of
             true -> vmadd(U, Dv, -Toi);
             false -> U
         end,
    {Dv, Dw, Du}.

%% Coulomb friction on top of the normal impulse JNormal (both on A).
friction(undefined, _Rot, _Jn, _Vrel, _Vn, _N, _K, _KRot, JNormal) -> JNormal;
friction(_Mu, _Rot, Jn, _Vrel, _Vn, _N, _K, _KRot, JNormal) when Jn =< 0.0 -> JNormal;
friction(Mu, Rot, Jn, Vrel, Vn, N, K, KRot, JNormal) ->
    Vt = vmadd(Vrel, N, -Vn),
    Lt = vlen(Vt),
    case Lt > ?TINY of
        true ->
            Kt = case Rot of true -> K + KRot; false -> K end,
            Jt = min(Lt / Kt, Mu * Jn),
            %% A is dragged along the motion of B relative to A
            vmadd(JNormal, Vt, Jt / Lt);
        false ->
            JNormal
    end.
