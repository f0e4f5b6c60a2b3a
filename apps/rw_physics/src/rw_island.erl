%% An island: spheres stepped together, one substep at a time, the way the
%% sequential reference steps every body: contacts with fixtures first, then
%% the contacts among the members, plus the effects of contacts with bodies
%% outside the island (given by the caller), summed per body in canonical
%% order of partner and integrated. Every contact among members is found
%% here, so members exchange no messages; a Time Warp entity that holds
%% bodies in persistent contact steps them with this.
%%
%% Contacts among members come from a neighbour list (a Verlet list): the
%% pairs whose centres were closer than the sum of their radii plus a skin
%% when the list was built. The list stays valid while no member has moved
%% more than half the skin away from where it was then, measured relative
%% to the first member's own move (a pile falling as one keeps its list);
%% with CCD, the spread of the substep's displacements counts too. A pair
%% not on a valid list is then farther apart than the sum of their radii
%% by a margin far above rounding, so the list finds exactly the contacts
%% a test of every pair finds.
%%
%% Fixtures are listed per member the same way: those within its radius
%% plus half a skin (one radius) of where it was when the list was built,
%% valid while it stays within half a skin of there (absolutely: fixtures
%% do not move), with CCD counting twice its displacement (?CCD_REACH). A
%% member far from every post, wall and floor of a scene then tests none of
%% them: a sphere in free flight in a container checks its move from the
%% anchor, not the six walls, at each substep.
-module(rw_island).
-include("rw_physics.hrl").
-export([new/3, size/1, bodies/1, posts/3, step/3, post/3, advance/3, free_zone/1, near_zone/1, touches_no_fixture/4]).
-export_type([island/0, external/0]).
-include("rw_vec_inline.hrl").

%% How far a member's centre may get from where it starts the substep, in
%% free displacements, with CCD: after a bounce rw_dynamics sweeps the rest
%% of its path only while it stays within twice its free displacement.
-define(CCD_REACH, 2.0).

%% The effect of a contact with a body outside the island, for the member
%% whose idx is given, under its canonical key.
-type external() :: {MemberIdx :: non_neg_integer(), rw_dynamics:keyed_effect()}.

-record(island, {
    model :: #model{},
    spheres :: tuple(),                                 % #sphere{}, ascending idx
    pos :: #{non_neg_integer() => pos_integer()},       % member idx => position
    fixtures :: [#fixture{}],
    skin :: float(),
    %% the neighbour list: positions when it was built, how far a member
    %% may move from there, and the pairs {A, B} (positions, A < B) that
    %% may touch while no member has moved farther
    anchors = undefined :: tuple() | undefined,
    limit = 0.0 :: float(),
    pairs = [] :: [{pos_integer(), pos_integer()}],
    %% the fixtures each member may touch, while it stays within flimit of
    %% its fanchor
    near :: tuple(),
    fanchors = undefined :: tuple() | undefined,
    flimit = 0.0 :: float()
}).
-opaque island() :: #island{}.

-spec new(#model{}, [#sphere{}, ...], [#fixture{}]) -> island().
new(Model, Spheres0, Fixtures) ->
    Spheres = lists:keysort(#sphere.idx, Spheres0),
    RMax = lists:max([R || #sphere{radius = R} <- Spheres]),
    #island{model = Model, spheres = list_to_tuple(Spheres), fixtures = Fixtures,
            pos = maps:from_list(lists:zip([I || #sphere{idx = I} <- Spheres], lists:seq(1, length(Spheres)))),
            skin = 0.5 * RMax,
            near = list_to_tuple([Fixtures || _ <- Spheres])}.

-spec size(island()) -> pos_integer().
size(#island{spheres = S}) -> tuple_size(S).

%% The model, the members (ascending idx) and the fixtures: what step/3
%% steps, for the engine's C loop (rw_native), which steps the same.
-spec bodies(island()) -> {#model{}, tuple(), [#fixture{}]}.
bodies(#island{model = M, spheres = S, fixtures = F}) -> {M, S, F}.

%% Post-response velocities ({V, W, U}, as rw_dynamics:respond/2) of every
%% member at this substep, from their pre-response States (a tuple in idx
%% order) and the External effects.
-spec posts(island(), tuple(), [external()]) -> {tuple(), island()}.
posts(#island{spheres = {_}} = I0, {St}, External) ->
    {Post, I} = post(I0, St, External),
    {{Post}, I};
posts(#island{model = M, spheres = Spheres, pos = Pos} = I0, States, External) ->
    N = tuple_size(Spheres),
    Disps = displacements(M, States),
    {Pairs, I1} = neighbours(I0, States, Disps),
    #island{near = Near} = I = fixtures_near(I1, States, Disps),
    {Fixed, Seen} = fixed_and_seen(N, M, Spheres, States, Near, [], []),
    Outside = [{maps:get(Idx, Pos), Keyed} || {Idx, Keyed} <- External],
    Found = pair_effects(Pairs, M, Spheres, States, Seen, Disps, Outside),
    {list_to_tuple(each_post(N, by_member(Found, erlang:make_tuple(N, [])), States, Fixed, [])), I}.

%% Every member's fixture effects and the state its pair contacts see.
fixed_and_seen(0, _M, _Spheres, _States, _Near, Fixed, Seen) -> {list_to_tuple(Fixed), list_to_tuple(Seen)};
fixed_and_seen(K, M, Spheres, States, Near, Fixed, Seen) ->
    St = element(K, States),
    F = rw_dynamics:fixture_effects(M, element(K, Spheres), St, element(K, Near)),
    fixed_and_seen(K - 1, M, Spheres, States, Near, [F | Fixed], [rw_dynamics:after_fixtures(St, F) | Seen]).

%% The posts of members K..1, from each member's pair and outside effects
%% (by_member/2) in key order (keys are unique: partners, or a fixture's
%% features).
each_post(0, _Found, _States, _Fixed, Acc) -> Acc;
each_post(K, Found, States, Fixed, Acc) ->
    Mine = case element(K, Found) of
               [_, _ | _] = Many -> lists:sort(Many);
               OneOrNone -> OneOrNone
           end,
    each_post(K - 1, Found, States, Fixed, [respond(element(K, States), element(K, Fixed), Mine) | Acc]).

%% The pair and outside effects, {Position, Keyed}, gathered in a tuple by
%% member position: a member's own few are sorted, not all of them.
by_member([], Acc) -> Acc;
by_member([{K, Keyed} | Rest], Acc) -> by_member(Rest, setelement(K, Acc, [Keyed | element(K, Acc)])).

%% The posts at this substep, and the members' next pre-response states.
-spec step(island(), tuple(), [external()]) -> {tuple(), tuple(), island()}.
step(#island{model = M, spheres = {_}} = I0, {St}, External) ->
    {{V, W, U} = Post, I} = post(I0, St, External),
    {{Post}, {rw_integrate:advance(M, St, V, W, U)}, I};
step(#island{model = M} = I0, States, External) ->
    {Posts, I} = posts(I0, States, External),
    {Posts, advance(M, States, Posts), I}.

%% The members' next pre-response states from their post-response
%% velocities Posts.
-spec advance(#model{}, tuple(), tuple()) -> tuple().
advance(M, States, Posts) -> advance_all(tuple_size(States), M, States, Posts, []).

advance_all(0, _M, _States, _Posts, Acc) -> list_to_tuple(Acc);
advance_all(K, M, States, Posts, Acc) ->
    {V, W, U} = element(K, Posts),
    advance_all(K - 1, M, States, Posts, [rw_integrate:advance(M, element(K, States), V, W, U) | Acc]).

%% The post-response velocities of the one member of an island of one (the
%% most common entity, and the hot path of free flight): its fixtures and
%% the outside.
-spec post(island(), #st{}, [external()]) -> {{rw_vec:vec(), rw_vec:vec() | undefined, rw_vec:vec()}, island()}.
post(#island{model = M, spheres = {S}, fixtures = []} = I, St, External) ->
    {alone(M, S, St, [], External), I};
post(#island{model = #model{ccd = false} = M, spheres = {S}, near = {Near}, fanchors = {{AX, AY, AZ}}, flimit = Limit} = I,
     #st{p = {X, Y, Z}} = St, External)
  when is_float(X), is_float(Y), is_float(Z), is_float(AX), is_float(AY), is_float(AZ), is_float(Limit) ->
    %% within/6 for one member without CCD, written out (the hot path)
    DX = X - AX,
    DY = Y - AY,
    DZ = Z - AZ,
    case DX * DX + DY * DY + DZ * DZ =< Limit * Limit of
        true -> {alone(M, S, St, Near, External), I};
        false -> post(I#island{fanchors = undefined}, St, External)
    end;
post(#island{model = M, spheres = {S}} = I0, St, External) ->
    #island{near = {Near}} = I = fixtures_near(I0, {St}, displacements(M, {St})),
    {alone(M, S, St, Near, External), I}.

%% Where the one member of an island of one touches no fixture: post/3
%% then gives its own velocities back (with no outside contact) and keeps
%% the island as it is. always: the scene has no fixture; {X, Y, Z, L2}:
%% while its centre is within squared distance L2 of {X, Y, Z} (the test
%% post/3 makes, the same operations); none: post/3 must say.
-spec free_zone(island()) -> always | {float(), float(), float(), float()} | none.
free_zone(#island{spheres = {_}, fixtures = []}) -> always;
free_zone(#island{model = #model{ccd = false}, spheres = {_}, near = {[]}, fanchors = {{AX, AY, AZ}}, flimit = Limit})
  when is_float(Limit) ->
    {AX, AY, AZ, Limit * Limit};
free_zone(_) -> none.

%% Where an island of one without a free zone (fixtures listed near) is
%% free all the same, for touches_no_fixture/4's own test elsewhere (the
%% engine's C loop, rw_native): the anchor, how far the member may move from
%% it, its radius and the fixtures it may touch; none for any other island.
-spec near_zone(island()) -> {near, float(), float(), float(), float(), float(), [#fixture{}]} | none.
near_zone(#island{model = #model{ccd = false}, spheres = {#sphere{radius = R}}, near = {Near},
                  fanchors = {{AX, AY, AZ}}, flimit = Limit}) ->
    {near, AX, AY, AZ, Limit, R, Near};
near_zone(_) -> none.

%% Whether the one member of an island of one, at position {X, Y, Z} and
%% with no contact from outside, touches none of its fixtures by post/3's
%% own tests while it stays within reach of its anchor: then post/3 gives
%% its own velocities back and keeps the island as it is, as in its free
%% zone. (A sphere near a wall is out of its free zone for many substeps
%% on end without touching it.)
-spec touches_no_fixture(island(), float(), float(), float()) -> boolean().
touches_no_fixture(#island{model = #model{ccd = false}, spheres = {#sphere{radius = R}}, near = {Near},
                           fanchors = {{AX, AY, AZ}}, flimit = Limit}, X, Y, Z)
  when is_float(X), is_float(Y), is_float(Z), is_float(AX), is_float(AY), is_float(AZ), is_float(Limit) ->
    DX = X - AX,
    DY = Y - AY,
    DZ = Z - AZ,
    DX * DX + DY * DY + DZ * DZ =< Limit * Limit andalso not rw_dynamics:touches_fixture({X, Y, Z}, R, Near);
touches_no_fixture(_I, _X, _Y, _Z) -> false.

alone(_M, _S, St, [], []) -> rw_dynamics:respond(St, []);
alone(M, S, St, Fixtures, []) -> respond(St, rw_dynamics:fixture_effects(M, S, St, Fixtures), []);
alone(M, S, St, Fixtures, External) ->
    respond(St, rw_dynamics:fixture_effects(M, S, St, Fixtures), lists:keysort(1, [Keyed || {_, Keyed} <- External])).

%% Sum a member's effects in canonical order: Fixed and Others are each
%% sorted by key, and keys are unique (a fixture's feature or a partner).
respond(St, [], []) -> rw_dynamics:respond(St, []);
respond(St, [{_, E}], []) -> rw_dynamics:respond(St, [E]);
respond(St, [], [{_, E}]) -> rw_dynamics:respond(St, [E]);
respond(St, Fixed, Others) -> rw_dynamics:respond(St, merge(Fixed, Others)).

%% The effects of two lists sorted by (unique) key, in key order.
merge([{KA, EA} | RA] = A, [{KB, EB} | RB] = B) ->
    case KA < KB of
        true -> [EA | merge(RA, B)];
        false -> [EB | merge(A, RB)]
    end;
merge([], B) -> [E || {_, E} <- B];
merge(A, []) -> [E || {_, E} <- A].

%%% Contacts among members

%% The effects of every contact among Pairs, added to Acc, as
%% {Position, {Key, Effect}}.
pair_effects([], _M, _Spheres, _States, _Seen, _Disps, Acc) -> Acc;
pair_effects([{A, B} | Rest], M, Spheres, States, Seen, Disps, Acc) ->
    #sphere{idx = IA, radius = RA} = SA = element(A, Spheres),
    #sphere{idx = IB, radius = RB} = SB = element(B, Spheres),
    #st{p = PA} = element(A, States),
    #st{p = PB} = element(B, States),
    Contact = case Disps of
                  undefined -> rw_narrow:sphere_sphere(PA, RA, PB, RB);
                  _ -> rw_narrow:swept_sphere_sphere(PA, element(A, Disps), RA, PB, element(B, Disps), RB)
              end,
    case Contact of
        none -> pair_effects(Rest, M, Spheres, States, Seen, Disps, Acc);
        _ ->
            {EA, EB} = rw_response:pair(M, SA, element(A, Seen), SB, element(B, Seen), Contact),
            pair_effects(Rest, M, Spheres, States, Seen, Disps, [{A, {{IB, 0}, EA}}, {B, {{IA, 0}, EB}} | Acc])
    end.

%% With CCD, each member's free displacement over the substep.
displacements(#model{ccd = false}, _States) -> undefined;
displacements(M, States) -> list_to_tuple([rw_integrate:free_displacement(M, St) || St <- tuple_to_list(States)]).

%%% The fixtures near each member

fixtures_near(#island{fixtures = []} = I, _States, _Disps) -> I;
fixtures_near(#island{fanchors = undefined} = I, States, Disps) -> fixtures_fresh(I, States, Disps);
fixtures_near(#island{fanchors = Anchors, flimit = Limit} = I, States, Disps) ->
    case within(States, Anchors, vzero(), Disps, vzero(), ?CCD_REACH, Limit) of
        true -> I;
        false -> fixtures_fresh(I, States, Disps)
    end.

%% The fixtures near each member now, kept while it stays within half a
%% skin of here; a list not valid even now (a displacement longer than
%% that) lists every fixture, and the next substep builds again.
fixtures_fresh(#island{spheres = Spheres, fixtures = Fixtures} = I, States, Disps) ->
    Anchors = list_to_tuple([P || #st{p = P} <- tuple_to_list(States)]),
    Reach = lists:max([R || #sphere{radius = R} <- tuple_to_list(Spheres)]),
    Scale = lists:max([rw_vec:max_abs(P) || P <- tuple_to_list(Anchors)]) + 2.0 * Reach,
    Limit = 0.5 * Reach - 1.0e-9 * Scale,
    case within(States, Anchors, vzero(), Disps, vzero(), ?CCD_REACH, Limit) of
        true ->
            Near = list_to_tuple([[F || F <- Fixtures, may_touch(F, element(K, Anchors), R + 0.5 * Reach)]
                                  || {K, #sphere{radius = R}} <- lists:zip(lists:seq(1, tuple_size(Spheres)),
                                                                           tuple_to_list(Spheres))]),
            I#island{near = Near, fanchors = Anchors, flimit = Limit};
        false ->
            I#island{near = list_to_tuple([Fixtures || _ <- tuple_to_list(Spheres)]), fanchors = undefined}
    end.

%% A fixture may touch a sphere whose centre stays within Reach of P: the
%% narrowphase rejects a sphere farther than its radius outside the box, on
%% the inner side of a plane by more than its radius, or farther than that
%% from every wall of a container. The distances to a plane or a wall are
%% rounded: a margin far above that rounding keeps a fixture listed when
%% they are about Reach.
may_touch(#fixture{shape = {plane, N, Off}, box = unbounded}, P, Reach) ->
    vdot(N, P) - Off < Reach + margin(P, Off, Reach);
may_touch(#fixture{shape = {box, {CX, CY, CZ}, {EX, EY, EZ}, hollow}, box = unbounded}, {X, Y, Z} = P, Reach) ->
    Near = Reach + margin(P, rw_vec:max_abs({CX + EX, CY + EY, CZ + EZ}) + rw_vec:max_abs({CX - EX, CY - EY, CZ - EZ}),
                          Reach),
    X - (CX - EX) < Near orelse (CX + EX) - X < Near orelse Y - (CY - EY) < Near orelse (CY + EY) - Y < Near orelse
        Z - (CZ - EZ) < Near orelse (CZ + EZ) - Z < Near;
may_touch(#fixture{box = unbounded}, _P, _Reach) -> true;
may_touch(#fixture{box = {X0, Y0, Z0, X1, Y1, Z1}}, {X, Y, Z}, Reach) ->
    not (X + Reach < X0 orelse X - Reach > X1 orelse Y + Reach < Y0 orelse Y - Reach > Y1 orelse
         Z + Reach < Z0 orelse Z - Reach > Z1).

margin(P, Far, Reach) -> 1.0e-9 * (rw_vec:max_abs(P) + abs(Far) + Reach).

%%% The neighbour list

%% The pairs to test at this substep: those of the list while it is valid
%% for States (rebuilt when it is not). A list that is not valid even when
%% just built (with CCD, displacements that differ by more than half the
%% skin; coordinates so large that the rounding margin exceeds it) is not
%% used: every pair is tested, and the next substep builds again.
neighbours(#island{anchors = undefined} = I, States, Disps) -> fresh(I, States, Disps);
neighbours(#island{anchors = Anchors, limit = Limit, pairs = Pairs} = I, States, Disps) ->
    case valid(States, Anchors, Disps, Limit) of
        true -> {Pairs, I};
        false -> fresh(I, States, Disps)
    end.

fresh(I0, States, Disps) ->
    #island{anchors = Anchors, limit = Limit, pairs = Pairs} = I = build(I0, States),
    case valid(States, Anchors, Disps, Limit) of
        true -> {Pairs, I};
        false ->
            N = tuple_size(States),
            {[{A, B} || A <- lists:seq(1, N), B <- lists:seq(A + 1, N)], I#island{anchors = undefined}}
    end.

%% Every member within Limit of its anchor, relative to the first member's
%% move, adding (with CCD) how far its displacement differs from the first
%% member's.
valid(States, Anchors, Disps, Limit) ->
    #st{p = P1} = element(1, States),
    Disp1 = case Disps of
                undefined -> undefined;
                _ -> element(1, Disps)
            end,
    within(States, Anchors, vsub(P1, element(1, Anchors)), Disps, Disp1, 1.0, Limit).

%% Every member moved less than Limit from its anchor, less Drift, plus
%% (with CCD) Times its displacement less Disp0: the test of both lists,
%% the fixtures' with no drift, no reference displacement (fixtures do not
%% move) and ?CCD_REACH times. Without CCD it compares squared distances:
%% no square root per member and substep; a list judged valid either way
%% has its margin, so a decision that rounding could tip only rebuilds a
%% list one substep early or late.
within(_States, _Anchors, _Drift, undefined, _Disp0, _Times, Limit) when Limit =< 0.0 -> false;
within(States, Anchors, Drift, undefined, _Disp0, _Times, Limit) ->
    within2(tuple_size(States), States, Anchors, Drift, Limit * Limit);
within(States, Anchors, Drift, Disps, Disp0, Times, Limit) ->
    within(tuple_size(States), States, Anchors, Drift, Disps, Disp0, Times, Limit).

within2(0, _States, _Anchors, _Drift, _Limit2) -> true;
within2(K, States, Anchors, Drift, Limit2) ->
    #st{p = P} = element(K, States),
    case vlen2(vsub(vsub(P, element(K, Anchors)), Drift)) =< Limit2 of
        true -> within2(K - 1, States, Anchors, Drift, Limit2);
        false -> false
    end.

within(0, _States, _Anchors, _Drift, _Disps, _Disp0, _Times, _Limit) -> true;
within(K, States, Anchors, Drift, Disps, Disp0, Times, Limit) ->
    #st{p = P} = element(K, States),
    Moved = vlen(vsub(vsub(P, element(K, Anchors)), Drift)),
    case Moved + Times * vlen(vsub(element(K, Disps), Disp0)) =< Limit of
        true -> within(K - 1, States, Anchors, Drift, Disps, Disp0, Times, Limit);
        false -> false
    end.

%% The pairs closer than the sum of their radii plus the skin, by sweep and
%% prune (rw_broadphase:sweep/2): each member against those within its
%% radius plus the largest radius plus the skin along x, y and z.
build(#island{spheres = Spheres, skin = Skin} = I, States) ->
    N = tuple_size(Spheres),
    Anchors = list_to_tuple([P || #st{p = P} <- tuple_to_list(States)]),
    RMax = lists:max([R || #sphere{radius = R} <- tuple_to_list(Spheres)]),
    Items = [{X, K, Y, Z, R, R + RMax + Skin}
             || K <- lists:seq(1, N), #sphere{radius = R} <- [element(K, Spheres)], {X, Y, Z} <- [element(K, Anchors)]],
    Pairs = rw_broadphase:sweep(Items, {skin, Skin}),
    Scale = lists:max([rw_vec:max_abs(P) || P <- tuple_to_list(Anchors)]) + RMax + Skin,
    %% half the skin, less a margin far above the rounding of the positions
    Limit = 0.5 * Skin - 1.0e-9 * Scale,
    I#island{anchors = Anchors, pairs = Pairs, limit = Limit}.
