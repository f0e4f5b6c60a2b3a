%% Unit quaternions as {{X,Y,Z},W} so that they never pass for vectors.
-module(rw_quat).
-compile(inline).
-export([identity/0, mul/2, norm/1, integrate/3, rotate/2]).
-export_type([quat/0]).

-type quat() :: {rw_vec:vec(), float()}.
-include("rw_vec_inline.hrl").

-spec identity() -> quat().
identity() -> {{0.0, 0.0, 0.0}, 1.0}.

-spec mul(quat(), quat()) -> quat().
mul({V1, W1}, {V2, W2}) when is_float(W1), is_float(W2) ->
    V = vadd(vadd(vscale(V2, W1), vscale(V1, W2)), vcross(V1, V2)),
    {V, W1 * W2 - vdot(V1, V2)}.

-spec norm(quat()) -> quat().
norm({V, W} = Q) when is_float(W) ->
    L = math:sqrt(vlen2(V) + W * W),
    case L > 0.0 of
        true -> {vscale(V, 1.0 / L), W / L};
        false -> Q
    end.

%% Orientation after turning at angular velocity Omega (rad/s) for Dt
%% seconds: q + dt/2 * (omega, 0) * q, renormalised.
-spec integrate(quat(), rw_vec:vec(), float()) -> quat().
%% (called once per body and substep: mul/2 and norm/1 written out, the
%% same operations in the same order, so the result is bit for bit theirs;
%% no spin, -0.0 too, leaves Q as it is, tested by guards rather than by
%% matching a literal tuple, which calls the runtime's term comparison)
integrate(Q, {OX, OY, OZ}, _Dt) when OX == 0.0, OY == 0.0, OZ == 0.0 -> Q;
integrate({{X, Y, Z}, W}, {OX, OY, OZ}, Dt)
  when is_float(X), is_float(Y), is_float(Z), is_float(W), is_float(OX), is_float(OY), is_float(OZ),
       is_float(Dt) ->
    %% mul({Omega, 0.0}, Q)
    DX = (X * 0.0 + OX * W) + (OY * Z - OZ * Y),
    DY = (Y * 0.0 + OY * W) + (OZ * X - OX * Z),
    DZ = (Z * 0.0 + OZ * W) + (OX * Y - OY * X),
    DW = 0.0 * W - (OX * X + OY * Y + OZ * Z),
    H = 0.5 * Dt,
    X1 = X + DX * H, Y1 = Y + DY * H, Z1 = Z + DZ * H, W1 = W + DW * H,
    %% norm/1
    L = math:sqrt(X1 * X1 + Y1 * Y1 + Z1 * Z1 + W1 * W1),
    case L > 0.0 of
        true -> S = 1.0 / L, {{X1 * S, Y1 * S, Z1 * S}, W1 / L};
        false -> {{X1, Y1, Z1}, W1}
    end.

-spec rotate(quat(), rw_vec:vec()) -> rw_vec:vec().
rotate({U, W}, V) ->
    %% v + 2w(u x v) + 2 u x (u x v)
    UV = vcross(U, V),
    vadd(V, vadd(vscale(UV, 2.0 * W), vscale(vcross(U, UV), 2.0))).
