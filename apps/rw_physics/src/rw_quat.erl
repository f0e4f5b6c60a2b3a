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
integrate(Q, {0.0, 0.0, 0.0}, _Dt) -> Q;
integrate({V, W} = Q, Omega, Dt) ->
    {DV, DW} = mul({Omega, 0.0}, Q),
    H = 0.5 * Dt,
    norm({vmadd(V, DV, H), W + DW * H}).

-spec rotate(quat(), rw_vec:vec()) -> rw_vec:vec().
rotate({U, W}, V) ->
    %% v + 2w(u x v) + 2 u x (u x v)
    UV = vcross(U, V),
    vadd(V, vadd(vscale(UV, 2.0 * W), vscale(vcross(U, UV), 2.0))).
