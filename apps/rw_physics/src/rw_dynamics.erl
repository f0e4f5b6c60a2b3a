%% One substep of one body, shared by both engines: from its pre-response
%% state and the effects of all its contacts at that substep (in canonical
%% order of partner), the post-response velocities and the next state.
%% Effects are always summed from the pre-response velocities in the same
%% order, never added to an already updated velocity, so the result does not
%% depend on the order in which contacts were discovered.
%%
%% Contacts with fixtures come first: a pair of spheres sees both spheres'
%% velocities after their own fixture contacts (after_fixtures/2), which each
%% body computes from its own state alone. A sphere pinned between a wall and
%% another sphere then bounces off the wall and exchanges momentum with the
%% sphere, as in nature, instead of summing two impulses that each assume
%% the other did not happen (at restitution 1 that loses kinetic energy:
%% 5 % of a box's in one substep).
-module(rw_dynamics).
-include("rw_physics.hrl").
-export([respond/2, step/3, fixture_effects/4, touches_fixture/3, after_fixtures/2]).
-export_type([keyed_effect/0]).

%% An effect under its canonical key: {partner or fixture idx, feature}.
-type keyed_effect() :: {{non_neg_integer(), non_neg_integer()}, rw_response:effect()}.
-include("rw_vec_inline.hrl").

-spec respond(#st{}, [rw_response:effect()]) ->
          {V :: rw_vec:vec(), W :: rw_vec:vec() | undefined, U :: rw_vec:vec()}.
respond(#st{v = V, w = W}, []) -> {V, W, {0.0, 0.0, 0.0}};
respond(#st{v = V, w = W}, Effects) ->
    sum(Effects, V, W, vzero()).

sum([], V, W, U) -> {V, W, U};
sum([{Dv, undefined, Du} | Rest], V, W, U) ->
    sum(Rest, vadd(V, Dv), W, vadd(U, Du));
sum([{Dv, Dw, Du} | Rest], V, W, U) ->
    sum(Rest, vadd(V, Dv), vadd(W, Dw), vadd(U, Du)).

%% Next pre-response state.
-spec step(#model{}, #st{}, [rw_response:effect()]) -> #st{}.
step(M, St, Effects) ->
    {V, W, U} = respond(St, Effects),
    rw_integrate:advance(M, St, V, W, U).

%% The effects of a sphere's contacts with the fixtures at one substep, in
%% canonical order (fixtures ascending by idx, features ascending). Each
%% contact acts on the velocities left by those before it: summed from the
%% same velocities, two contacts with almost parallel normals (a floor and
%% a plane just above it, both hit within one swept substep) would each
%% reverse the approach, and at restitution 1 send the sphere off at three
%% times its speed, bounce after bounce. In turn, the second contact finds
%% the sphere already leaving and does nothing.
-spec fixture_effects(#model{}, #sphere{}, #st{}, [#fixture{}]) -> [keyed_effect()].
fixture_effects(#model{ccd = Ccd} = M, #sphere{radius = R} = S, #st{p = P} = St, Fixtures) ->
    Disp = case Ccd of
               true -> rw_integrate:free_displacement(M, St);
               false -> undefined
           end,
    case [{{FIdx, Feature}, C} || #fixture{idx = FIdx} = Fixture <- Fixtures,
                                  {Feature, C} <- fixture_contacts(P, Disp, R, Fixture)] of
        [] -> [];
        [{Key, C}] -> [{Key, rw_response:fixture(M, S, St, C)}];
        Contacts -> in_turn(M, S, St, Contacts)
    end.

in_turn(_M, _S, _St, []) -> [];
in_turn(M, S, St, [{Key, C} | Rest]) ->
    Keyed = {Key, rw_response:fixture(M, S, St, C)},
    [Keyed | in_turn(M, S, after_fixtures(St, [Keyed]), Rest)].

%% Whether a sphere of radius R at P touches one of Fixtures, as
%% fixture_effects/4 finds contacts without CCD (without building them
%% into effects).
-spec touches_fixture(rw_vec:vec(), float(), [#fixture{}]) -> boolean().
touches_fixture(_P, _R, []) -> false;
touches_fixture(P, R, [Fixture | Rest]) ->
    fixture_contacts(P, undefined, R, Fixture) =/= [] orelse touches_fixture(P, R, Rest).

fixture_contacts(P, undefined, R, Fixture) -> rw_narrow:fixture(P, R, Fixture);
fixture_contacts(P, Disp, R, Fixture) -> rw_narrow:swept_fixture(P, Disp, R, Fixture).

%% The state a sphere's pair contacts see: its velocities after the effects
%% of its fixture contacts (from fixture_effects/4).
-spec after_fixtures(#st{}, [keyed_effect()]) -> #st{}.
after_fixtures(St, []) -> St;
after_fixtures(St, Fixed) ->
    {V, W, _U} = respond(St, [E || {_, E} <- Fixed]),
    St#st{v = V, w = W}.
