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
%%
%% (The response is written out in coordinates, as the pair impulse is:
%% the contact with the floor is computed at almost every substep of every
%% resting body, and vector temporaries would be most of what it allocates.
%% Each coordinate is computed by the same operations in the same order as
%% with rw_vec, so results are bit for bit those.)
-spec fixture(#model{}, #sphere{}, #st{}, #contact{}) -> effect().
fixture(#model{rotation = Rot, gravity = G, dt = Dt} = M, #sphere{inv_mass = Im, inv_inertia = Ii, radius = R},
        #st{v = {VX, VY, VZ}, w = W}, #contact{n = {NX, NY, NZ}, depth = Depth, toi = Toi})
  when ?IS_VEC(VX, VY, VZ), ?IS_VEC(NX, NY, NZ), is_float(Im), is_float(Ii), is_float(R), is_float(Dt) ->
    %% the velocity after gravity
    {GvX, GvY, GvZ} = case G of
                          undefined -> {VX, VY, VZ};
                          {GX, GY, GZ} -> {VX + GX * Dt, VY + GY * Dt, VZ + GZ * Dt}
                      end,
    %% the pair impulse with B at rest, of zero radius and inverse mass
    %% (its contact point's velocity is exactly zero), less B's half: the
    %% relative velocity is 0 - (v + w x R n)
    {RelX, RelY, RelZ} = case Rot of
                             true ->
                                 {WX, WY, WZ} = W,
                                 AX = NX * R, AY = NY * R, AZ = NZ * R,
                                 {0.0 - (GvX + (WY * AZ - WZ * AY)), 0.0 - (GvY + (WZ * AX - WX * AZ)),
                                  0.0 - (GvZ + (WX * AY - WY * AX))};
                             false ->
                                 {0.0 - GvX, 0.0 - GvY, 0.0 - GvZ}
                         end,
    {JX, JY, JZ, Ub} = normal_friction(M, RelX, RelY, RelZ, NX, NY, NZ, Im + 0.0, R * R * Ii + 0.0, Depth),
    side(JX, JY, JZ, arm(Rot, NX, NY, NZ, JX, JY, JZ), Im, R * Ii, Ub, NX, NY, NZ, Toi).

impulse(#model{rotation = Rot} = M, ImA, IiA, RA, {VAX, VAY, VAZ}, WA, ImB, IiB, RB, {VBX, VBY, VBZ}, WB,
        #contact{n = {NX, NY, NZ}, depth = Depth, toi = Toi})
  when is_float(ImA), is_float(IiA), is_float(RA), is_float(ImB), is_float(IiB), is_float(RB),
       ?IS_VEC(VAX, VAY, VAZ), ?IS_VEC(VBX, VBY, VBZ), ?IS_VEC(NX, NY, NZ) ->
    %% the relative velocity of the two surface points in contact:
    %% (vB + wB x -RB n) - (vA + wA x RA n)
    {RelX, RelY, RelZ} = case Rot of
                             true ->
                                 {WAX, WAY, WAZ} = WA,
                                 {WBX, WBY, WBZ} = WB,
                                 AX = NX * RA, AY = NY * RA, AZ = NZ * RA,
                                 NRB = -RB,
                                 BX = NX * NRB, BY = NY * NRB, BZ = NZ * NRB,
                                 {(VBX + (WBY * BZ - WBZ * BY)) - (VAX + (WAY * AZ - WAZ * AY)),
                                  (VBY + (WBZ * BX - WBX * BZ)) - (VAY + (WAZ * AX - WAX * AZ)),
                                  (VBZ + (WBX * BY - WBY * BX)) - (VAZ + (WAX * AY - WAY * AX))};
                             false ->
                                 {VBX - VAX, VBY - VAY, VBZ - VAZ}
                         end,
    {JX, JY, JZ, Ub} = normal_friction(M, RelX, RelY, RelZ, NX, NY, NZ, ImA + ImB, RA * RA * IiA + RB * RB * IiB,
                                       Depth),
    %% (B receives the opposite impulse; r x J with r = RA n for A and
    %% r = -RB n, J = -JA for B: the same arm n x JA)
    Arm = arm(Rot, NX, NY, NZ, JX, JY, JZ),
    {side(JX, JY, JZ, Arm, ImA, RA * IiA, Ub, NX, NY, NZ, Toi), side(JX, JY, JZ, Arm, -ImB, RB * IiB, Ub, NX, NY, NZ, Toi)}.

%% The impulse J on A from the relative velocity Rel of the contact points
%% and the inverse masses K (and KRot of rotation), and the pseudo-impulse
%% Ub that removes penetration (none when nothing penetrates): {JX, JY, JZ, Ub}.
normal_friction(#model{rotation = Rot, restitution = E, rest_speed = RestSpeed, friction = Mu,
                       correction = Beta, slop = Slop, dt = Dt},
                RelX, RelY, RelZ, NX, NY, NZ, K, KRot, Depth)
  when ?IS_VEC(RelX, RelY, RelZ), ?IS_VEC(NX, NY, NZ), is_float(K), is_float(KRot), is_float(Depth),
       is_float(E), is_float(RestSpeed), is_float(Beta), is_float(Slop), is_float(Dt) ->
    Vn = RelX * NX + RelY * NY + RelZ * NZ,
    Jn = case Vn < 0.0 of
             true ->
                 Bounce = case -Vn > RestSpeed of true -> E; false -> 0.0 end,
                 -(1.0 + Bounce) * Vn / K;
             false -> 0.0
         end,
    Pen = Depth - Slop,
    Ub = case Pen > 0.0 of
             true -> Beta * Pen / Dt / K;
             false -> none
         end,
    %% the normal impulse -Jn n, and Coulomb friction on top of it
    MJn = -Jn,
    JnX = NX * MJn, JnY = NY * MJn, JnZ = NZ * MJn,
    case is_float(Mu) andalso Jn > 0.0 of
        false ->
            {JnX, JnY, JnZ, Ub};
        true ->
            %% A is dragged along the motion of B relative to A
            MVn = -Vn,
            TX = RelX + NX * MVn, TY = RelY + NY * MVn, TZ = RelZ + NZ * MVn,
            Lt = math:sqrt(TX * TX + TY * TY + TZ * TZ),
            case Lt > ?TINY of
                true ->
                    Kt = case Rot of true -> K + KRot; false -> K end,
                    S = min(Lt / Kt, Mu * Jn) / Lt,
                    {JnX + TX * S, JnY + TY * S, JnZ + TZ * S, Ub};
                false ->
                    {JnX, JnY, JnZ, Ub}
            end
    end.

%% n x J with rotation, else undefined.
arm(true, NX, NY, NZ, JX, JY, JZ) when ?IS_VEC(NX, NY, NZ), ?IS_VEC(JX, JY, JZ) ->
    {NY * JZ - NZ * JY, NZ * JX - NX * JZ, NX * JY - NY * JX};
arm(false, _NX, _NY, _NZ, _JX, _JY, _JZ) -> undefined.

%% One body's effect: impulse J (on A) scaled by its signed inverse mass
%% Im (negative for B), its angular change from Arm, and its pseudo-velocity
%% against n (-Ub Im, zero when nothing penetrates); a swept contact at
%% fraction Toi moves with the old velocity until then.
side(JX, JY, JZ, Arm, Im, ArmScale, Ub, NX, NY, NZ, Toi)
  when ?IS_VEC(JX, JY, JZ), ?IS_VEC(NX, NY, NZ), is_float(Im), is_float(ArmScale), is_float(Toi) ->
    DvX = JX * Im, DvY = JY * Im, DvZ = JZ * Im,
    Dw = case Arm of
             undefined -> undefined;
             {AX, AY, AZ} -> {AX * ArmScale, AY * ArmScale, AZ * ArmScale}
         end,
    Du = case {Ub, Toi > 0.0} of
             {none, false} -> {0.0, 0.0, 0.0};
             {none, true} -> MToi = -Toi, {0.0 + DvX * MToi, 0.0 + DvY * MToi, 0.0 + DvZ * MToi};
             {_, false} -> S = -Ub * Im, {NX * S, NY * S, NZ * S};
             {_, true} -> S = -Ub * Im, MToi = -Toi, {NX * S + DvX * MToi, NY * S + DvY * MToi, NZ * S + DvZ * MToi}
         end,
    {{DvX, DvY, DvZ}, Dw, Du}.
