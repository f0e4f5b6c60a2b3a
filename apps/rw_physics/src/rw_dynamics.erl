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
%%
%% With CCD a sphere that already touches fixtures at the start of the
%% substep meets those first, in turn as above; then it meets what its
%% path reaches, one impact at a time: the earliest contact along the
%% path, after which the rest of the path is swept again from the point of
%% impact (impacts/10). A sphere that crosses a narrow gap or a small
%% container within one substep meets the far wall too, instead of passing
%% through it. A sphere whose path reaches nothing (one resting on a floor
%% touches it at the start) sweeps only once.
-spec fixture_effects(#model{}, #sphere{}, #st{}, [#fixture{}]) -> [keyed_effect()].
fixture_effects(#model{ccd = false} = M, #sphere{radius = R} = S, #st{p = P} = St, Fixtures) ->
    in_turn(M, S, St, contacts(P, undefined, R, Fixtures));
fixture_effects(M, #sphere{radius = R} = S, #st{p = P} = St, Fixtures) ->
    Disp = rw_integrate:free_displacement(M, St),
    case contacts(P, Disp, R, Fixtures) of
        [] -> [];
        Contacts ->
            case lists:partition(fun({_, #contact{toi = Toi}}) -> Toi > 0.0 end, Contacts) of
                {[], Now} -> in_turn(M, S, St, Now);
                {Later, Now} ->
                    Touched = in_turn(M, S, St, Now),
                    impacts(M, S, St, after_fixtures(St, Touched), Fixtures, Touched, 0.0, Later, 2.0 * vlen(Disp), 1)
            end
    end.

contacts(P, Disp, R, Fixtures) ->
    [{{FIdx, Feature}, C} || #fixture{idx = FIdx} = Fixture <- Fixtures,
                             {Feature, C} <- fixture_contacts(P, Disp, R, Fixture)].

in_turn(_M, _S, _St, []) -> [];
in_turn(M, S, St, [{Key, C}]) -> [{Key, rw_response:fixture(M, S, St, C)}];
in_turn(M, S, St, [{Key, C} | Rest]) ->
    Keyed = {Key, rw_response:fixture(M, S, St, C)},
    [Keyed | in_turn(M, S, after_fixtures(St, [Keyed]), Rest)].

%% The sphere has met Effects (in the order they acted), which left it
%% with the velocities of After, the last of them at fraction Last of the
%% substep. Of the Contacts along the path from
%% there (their toi a fraction of that path), the earliest that the sphere
%% approaches is the next impact (one it leaves, as in a corner it has just
%% bounced out of, is passed over); its effect acts from then on (its toi
%% made a fraction of the whole substep), and the path from there is swept
%% next. A feature met again is keyed {Fixture, {Feature, Pass}}, so that
%% keys stay unique; the effects are returned in key order.
impacts(_M, _S, _St, _After, _Fixtures, Effects, _Last, [], _Reach, _Pass) -> lists:keysort(1, Effects);
impacts(M, S, St, After, Fixtures, Effects, Last, Contacts, Reach, Pass) ->
    {{FIdx, Feature} = Key, #contact{toi = Along} = C} = First = first_impact(Contacts),
    Toi = Last + Along * (1.0 - Last),
    case rw_response:fixture(M, S, After, C#contact{toi = Toi}) of
        {{DX, DY, DZ}, _, _} when DX == 0.0, DY == 0.0, DZ == 0.0 ->
            %% (zeros of either sign)
            impacts(M, S, St, After, Fixtures, Effects, Last, lists:delete(First, Contacts), Reach, Pass);
        Effect ->
            Unique = case lists:keymember(Key, 1, Effects) of
                         false -> Key;
                         true -> {FIdx, {Feature, Pass}}
                     end,
            next_leg(M, S, St, Fixtures, Effects ++ [{Unique, Effect}], Toi, Reach, Pass + 1)
    end.

%% The path from fraction Last of the substep on: a straight leg (the
%% displacement the sphere's velocities now give over a whole substep,
%% times 1 - Last) that ends where the effects so far put the sphere. A
%% feature it touches at its start is a contact there only if the sphere
%% has not met it yet (it is in contact with the one it has just met).
%% The legs are swept while every point of them lies within Reach (twice
%% the untouched displacement) of where the sphere started, so that
%% rw_island, which lists the fixtures within that reach, finds what the
%% whole list finds, and for at most ?PASSES impacts: a sphere wedged
%% between two walls at a speed that would bounce it more often within
%% one substep passes.
-define(PASSES, 64).
next_leg(_M, _S, _St, _Fixtures, Effects, _Last, _Reach, Pass) when Pass > ?PASSES -> lists:keysort(1, Effects);
next_leg(M, #sphere{radius = R} = S, #st{p = P} = St, Fixtures, Effects, Last, Reach, Pass) ->
    {V, W, U} = respond(St, [E || {_, E} <- Effects]),
    %% (positions only: the rotation is not integrated)
    Plain = M#model{rotation = false},
    #st{p = End} = rw_integrate:advance(Plain, St, V, W, U),
    Leg = vscale(rw_integrate:free_displacement(Plain, St#st{v = V}), 1.0 - Last),
    Start = vsub(End, Leg),
    case vlen(vsub(Start, P)) + vlen(Leg) =< Reach of
        true ->
            Met = [met_key(K) || {K, _} <- Effects],
            Next = [KC || {Key, #contact{toi = Toi}} = KC <- contacts(Start, Leg, R, Fixtures),
                          Toi > 0.0 orelse not lists:member(Key, Met)],
            impacts(M, S, St, St#st{v = V, w = W}, Fixtures, Effects, Last, Next, Reach, Pass);
        false ->
            lists:keysort(1, Effects)
    end.

met_key({FIdx, {Feature, _Pass}}) -> {FIdx, Feature};
met_key(Key) -> Key.

%% The earliest of some contacts; of several at once, the first in key
%% order.
first_impact([First | Rest]) ->
    lists:foldl(fun({_, #contact{toi = T}} = KC, {_, #contact{toi = Best}}) when T < Best -> KC;
                   (_, Acc) -> Acc
                end, First, Rest).

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
