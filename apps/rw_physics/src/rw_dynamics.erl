%% One substep of one body, shared by both engines: from its pre-response
%% state and the effects of all its contacts at that substep (in canonical
%% order of partner), the post-response velocities and the next state.
%% Effects are always summed from the pre-response velocities in the same
%% order, never added to an already updated velocity, so the result does not
%% depend on the order in which contacts were discovered.
-module(rw_dynamics).
-include("rw_physics.hrl").
-export([respond/2, step/3]).

-spec respond(#st{}, [rw_response:effect()]) ->
          {V :: rw_vec:vec(), W :: rw_vec:vec() | undefined, U :: rw_vec:vec()}.
respond(#st{v = V, w = W}, []) -> {V, W, {0.0, 0.0, 0.0}};
respond(#st{v = V, w = W}, Effects) ->
    sum(Effects, V, W, rw_vec:zero()).

sum([], V, W, U) -> {V, W, U};
sum([{Dv, undefined, Du} | Rest], V, W, U) ->
    sum(Rest, rw_vec:add(V, Dv), W, rw_vec:add(U, Du));
sum([{Dv, Dw, Du} | Rest], V, W, U) ->
    sum(Rest, rw_vec:add(V, Dv), rw_vec:add(W, Dw), rw_vec:add(U, Du)).

%% Next pre-response state.
-spec step(#model{}, #st{}, [rw_response:effect()]) -> #st{}.
step(M, St, Effects) ->
    {V, W, U} = respond(St, Effects),
    rw_integrate:advance(M, St, V, W, U).
