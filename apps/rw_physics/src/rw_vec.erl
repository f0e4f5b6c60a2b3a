%% 3-vectors as {X,Y,Z} float tuples. Small, inlined, no processes.
-module(rw_vec).
-compile(inline).
-export([zero/0, add/2, sub/2, scale/2, madd/3, dot/2, cross/2, len/1, len2/1,
         norm/1, neg/1, is_finite/1, max_abs/1]).
-export_type([vec/0]).

-type vec() :: {float(), float(), float()}.

-spec zero() -> vec().
zero() -> {0.0, 0.0, 0.0}.

-spec add(vec(), vec()) -> vec().
add({A, B, C}, {D, E, F}) -> {A + D, B + E, C + F}.

-spec sub(vec(), vec()) -> vec().
sub({A, B, C}, {D, E, F}) -> {A - D, B - E, C - F}.

-spec scale(vec(), float()) -> vec().
scale({A, B, C}, S) -> {A * S, B * S, C * S}.

%% A + B * S, the workhorse of integration.
-spec madd(vec(), vec(), float()) -> vec().
madd({A, B, C}, {D, E, F}, S) -> {A + D * S, B + E * S, C + F * S}.

-spec dot(vec(), vec()) -> float().
dot({A, B, C}, {D, E, F}) -> A * D + B * E + C * F.

-spec cross(vec(), vec()) -> vec().
cross({A, B, C}, {D, E, F}) -> {B * F - C * E, C * D - A * F, A * E - B * D}.

-spec len2(vec()) -> float().
len2({A, B, C}) -> A * A + B * B + C * C.

-spec len(vec()) -> float().
len(V) -> math:sqrt(len2(V)).

%% Unit vector; the zero vector has no direction and is returned as is.
-spec norm(vec()) -> vec().
norm(V) ->
    case len(V) of
        L when L > 0.0 -> scale(V, 1.0 / L);
        _ -> V
    end.

-spec neg(vec()) -> vec().
neg({A, B, C}) -> {-A, -B, -C}.

%% Erlang floats are always finite (arithmetic raises instead of producing
%% Inf/NaN), so this only checks the type.
-spec is_finite(term()) -> boolean().
is_finite({A, B, C}) -> is_float(A) andalso is_float(B) andalso is_float(C);
is_finite(_) -> false.

-spec max_abs(vec()) -> float().
max_abs({A, B, C}) -> max(abs(A), max(abs(B), abs(C))).
