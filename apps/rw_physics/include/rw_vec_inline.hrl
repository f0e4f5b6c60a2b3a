%% Local, inlined copies of the rw_vec functions for the physics' hot paths.
%% A call to rw_vec:add/2 from another module is a remote call that the
%% compiler cannot inline, and its arithmetic sees operands of unknown type;
%% these are expanded in place, and their is_float/1 guards let the compiler
%% keep the arithmetic in float registers. They compute exactly what rw_vec
%% computes, operation for operation, so results are bit for bit the same
%% (a pair impulse through rw_vec takes nearly twice as long).
-compile({inline, [vzero/0, vadd/2, vsub/2, vscale/2, vmadd/3, vdot/2, vcross/2, vlen2/1, vlen/1, vneg/1]}).
-compile({nowarn_unused_function, [vzero/0, vadd/2, vsub/2, vscale/2, vmadd/3, vdot/2, vcross/2, vlen2/1,
                                   vlen/1, vneg/1]}).

-define(IS_VEC(A, B, C), is_float(A), is_float(B), is_float(C)).

vzero() -> {0.0, 0.0, 0.0}.

vadd({A, B, C}, {D, E, F}) when ?IS_VEC(A, B, C), ?IS_VEC(D, E, F) -> {A + D, B + E, C + F}.

vsub({A, B, C}, {D, E, F}) when ?IS_VEC(A, B, C), ?IS_VEC(D, E, F) -> {A - D, B - E, C - F}.

vscale({A, B, C}, S) when ?IS_VEC(A, B, C), is_float(S) -> {A * S, B * S, C * S}.

%% A + B * S
vmadd({A, B, C}, {D, E, F}, S) when ?IS_VEC(A, B, C), ?IS_VEC(D, E, F), is_float(S) ->
    {A + D * S, B + E * S, C + F * S}.

vdot({A, B, C}, {D, E, F}) when ?IS_VEC(A, B, C), ?IS_VEC(D, E, F) -> A * D + B * E + C * F.

vcross({A, B, C}, {D, E, F}) when ?IS_VEC(A, B, C), ?IS_VEC(D, E, F) ->
    {B * F - C * E, C * D - A * F, A * E - B * D}.

vlen2({A, B, C}) when ?IS_VEC(A, B, C) -> A * A + B * B + C * C.

vlen(V) -> math:sqrt(vlen2(V)).

vneg({A, B, C}) when ?IS_VEC(A, B, C) -> {-A, -B, -C}.
