%% An exact, event-driven solver for spheres without rotation or friction,
%% optionally under uniform gravity, against half-space planes and the faces
%% of axis-aligned boxes: bodies move ballistically between exactly computed
%% times of impact, and each impact applies the restitution impulse along the
%% line of centres (or the face normal). It is the yardstick of
%% `rigidwarp bench accuracy` (rw_accuracy): the engines' substepped results
%% are compared with it.
%%
%% Times are in seconds here. A sphere whose bounce off a wall that gravity
%% presses it against is slower than ?REST_SPEED is put to rest on it
%% (restitution < 1 would otherwise make infinitely many bounces before a
%% finite time); a resting sphere slides frictionlessly along the wall under
%% the tangential part of gravity until another sphere hits it. A solid box is six
%% bounded faces; a sphere that would meet one of its edges or corners is
%% not modelled (error {unsupported, ...}), nor are cylinders.
-module(rw_exact).
-export([run/3, pair_toi/6, plane_toi/6, walls/1]).
-export_type([body/0, world/0, frame/0, wall/0]).

-type body() :: #{id := binary(), r := float(), m := float(), p := rw_vec:vec(), v := rw_vec:vec(),
                  resting => {pos_integer(), rw_vec:vec()}}.
%% A half-space whose solid side is where N.x is less than Off, or one face
%% of a solid axis-aligned box: the same half-space, bounded to the face's
%% rectangle.
-type wall() :: {N :: rw_vec:vec(), Off :: float()}
              | {N :: rw_vec:vec(), Off :: float(), {Centre :: rw_vec:vec(), HalfExtents :: rw_vec:vec()}}.
-type world() :: #{gravity := rw_vec:vec() | undefined, restitution := float(), planes := [wall()]}.
-type frame() :: {Tms :: number(), [{binary(), rw_vec:vec(), rw_vec:vec()}]}.

-define(REST_SPEED, 1.0e-9).
-define(MAX_EVENTS, 1000000).

%% The states at each of FrameTimes (ms, ascending) and the impacts that
%% happened: {Frames, Events} with Events = [{Tseconds, What}] in order,
%% What = {pair, I, J} (1-based positions in Bodies) or {plane, I, K}
%% (K-th wall of the world).
-spec run(world(), [body()], [number()]) -> {[frame()], [{float(), term()}]}.
run(World, Bodies, FrameTimes) ->
    Bs = list_to_tuple(Bodies),
    step(World, Bs, 0.0, next_event(World, Bs, 0.0), FrameTimes, [], [], 0).

%% Next is the earliest impact from the current state, {Tabs, Event} or
%% none: it stays valid while only frames are taken (free flight is exact),
%% and is recomputed after every impact.
step(_W, _Bs, _T, _Next, [], Frames, Events, _N) ->
    {lists:reverse(Frames), lists:reverse(Events)};
step(_W, _Bs, _T, _Next, _Left, _Frames, _Events, N) when N > ?MAX_EVENTS ->
    error(too_many_events);
step(W, Bs, T, Next, [Fms | Rest] = Frames0, Frames, Events, N) ->
    Tf = Fms / 1000,
    case Next of
        {Te, Event} when Te =< Tf ->
            Bs1 = collide(W, Event, drift(W, Bs, Te - T)),
            step(W, Bs1, Te, next_event(W, Bs1, Te), Frames0, Frames, [{Te, Event} | Events], N + 1);
        _ ->
            Bs1 = drift(W, Bs, Tf - T),
            Snapshot = {Fms, [{Id, P, V} || #{id := Id, p := P, v := V} <- tuple_to_list(Bs1)]},
            step(W, Bs1, Tf, Next, Rest, [Snapshot | Frames], Events, N)
    end.

%% The earliest impact after T: {Tabs, {pair, I, J} | {plane, I, K}} or none.
next_event(#{planes := Planes} = W, Bs, T) ->
    N = tuple_size(Bs),
    Pairs = [{Dt, {pair, I, J}}
             || I <- lists:seq(1, N), J <- lists:seq(I + 1, N),
                Dt <- pair_event(element(I, Bs), element(J, Bs))],
    Walls = [{Dt, {plane, I, K}}
             || I <- lists:seq(1, N),
                {K, Wall} <- lists:zip(lists:seq(1, length(Planes)), Planes),
                not resting_on(element(I, Bs), K),
                Dt <- plane_event(W, element(I, Bs), Wall)],
    case lists:sort(Pairs ++ Walls) of
        [] -> none;
        [{Dt, Event} | _] -> {T + Dt, Event}
    end.

resting_on(#{resting := {K, _}}, K) -> true;
resting_on(_, _) -> false.

pair_event(#{p := PA, v := VA, r := RA}, #{p := PB, v := VB, r := RB}) ->
    case pair_toi(PA, VA, RA, PB, VB, RB) of
        none -> [];
        Dt -> [Dt]
    end.

plane_event(#{gravity := G}, #{p := P, v := V, r := R}, {N, Off}) ->
    case plane_toi(P, V, G, R, N, Off) of
        none -> [];
        Dt -> [Dt]
    end;
plane_event(#{gravity := G} = W, #{p := P, v := V, r := R} = B, {N, Off, {C, E}}) ->
    case plane_toi(P, V, G, R, N, Off) of
        none -> [];
        Dt ->
            %% where the sphere touches the face's plane: inside the face, on
            %% its rim (an edge or corner: not modelled) or beside the box
            #{p := P1} = drift_one(G, B, Dt),
            Touch = rw_vec:madd(P1, N, -R),
            Behind = rw_vec:dot(N, P1) < Off,      % the centre is past the face: not its side
            Out = [abs(element(I, Touch) - element(I, C)) - element(I, E)
                   || I <- [1, 2, 3], element(I, N) == 0.0],
            Tol = 1.0e-9 * max(1.0, rw_vec:max_abs(C) + rw_vec:max_abs(E)),
            case lists:max(Out) of
                _ when Behind -> [];
                Most when Most =< Tol -> [Dt];
                _ ->
                    case lists:all(fun(D) -> D < R end, Out) of
                        true -> error({unsupported, {edge_or_corner_impact, maps:get(id, B), W}});
                        false -> []
                    end
            end
    end.

%% Time until two spheres moving apart by constant relative velocity touch
%% while approaching (uniform gravity does not change relative motion).
-spec pair_toi(rw_vec:vec(), rw_vec:vec(), float(), rw_vec:vec(), rw_vec:vec(), float()) -> float() | none.
pair_toi(PA, VA, RA, PB, VB, RB) ->
    Dp = rw_vec:sub(PB, PA),
    Dv = rw_vec:sub(VB, VA),
    A = rw_vec:dot(Dv, Dv),
    B = 2.0 * rw_vec:dot(Dp, Dv),
    C = rw_vec:dot(Dp, Dp) - (RA + RB) * (RA + RB),
    if
        B >= 0.0 -> none;                       % not approaching
        C =< 0.0 -> 0.0;                        % touching now and approaching
        true ->
            Disc = B * B - 4.0 * A * C,
            case Disc < 0.0 of
                true -> none;
                false -> (-B - math:sqrt(Disc)) / (2.0 * A)
            end
    end.

%% Time until a sphere reaches the plane N.x = Off from its positive side
%% while approaching it, under gravity G (or none).
-spec plane_toi(rw_vec:vec(), rw_vec:vec(), rw_vec:vec() | undefined, float(), rw_vec:vec(), float()) ->
          float() | none.
plane_toi(P, V, G, R, N, Off) ->
    H = rw_vec:dot(N, P) - Off - R,             % height above touching
    Vn = rw_vec:dot(N, V),
    An = case G of undefined -> 0.0; _ -> rw_vec:dot(N, G) end,
    if
        H =< 0.0, Vn < 0.0 -> 0.0;
        H =< 0.0, Vn =:= 0.0, An < 0.0 -> 0.0;
        An =:= 0.0 -> case Vn < 0.0 of true -> -H / Vn; false -> none end;
        true ->
            %% H + Vn t + An t^2 / 2 = 0: the first root after now at which
            %% the sphere is coming down (also after a bounce, when H is 0
            %% give or take rounding and it is going up)
            Disc = Vn * Vn - 2.0 * An * H,
            case Disc < 0.0 of
                true -> none;
                false ->
                    Sq = math:sqrt(Disc),
                    Roots = lists:sort([T || T <- [(-Vn - Sq) / An, (-Vn + Sq) / An],
                                             T > 0.0, Vn + An * T < 0.0]),
                    case Roots of [] -> none; [T | _] -> T end
            end
    end.

%% A fixture as the walls of the exact solver: a plane is itself; a hollow
%% box (a container) is six half-spaces facing its centre; a solid box is
%% its six faces, each bounded to its rectangle. Cylinders are not modelled.
-spec walls(rw_shape:static_shape()) -> [wall()].
walls({plane, N, Off}) -> [{N, Off}];
walls({box, C, E, hollow}) ->
    [{unit(Axis, 1.0), element(Axis, C) - element(Axis, E)} || Axis <- [1, 2, 3]] ++
        [{unit(Axis, -1.0), -(element(Axis, C) + element(Axis, E))} || Axis <- [1, 2, 3]];
walls({box, C, E, solid}) ->
    [{unit(Axis, S), S * element(Axis, C) + element(Axis, E), {C, E}} || Axis <- [1, 2, 3], S <- [-1.0, 1.0]];
walls(Other) ->
    error({unsupported, element(1, Other)}).

unit(1, S) -> {S, 0.0, 0.0};
unit(2, S) -> {0.0, S, 0.0};
unit(3, S) -> {0.0, 0.0, S}.

drift(#{gravity := G}, Bs, Dt) ->
    list_to_tuple([drift_one(G, B, Dt) || B <- tuple_to_list(Bs)]).

drift_one(_G, #{resting := {_, Gt}, p := P, v := V} = B, Dt) ->
    B#{p := rw_vec:madd(rw_vec:madd(P, V, Dt), Gt, 0.5 * Dt * Dt), v := rw_vec:madd(V, Gt, Dt)};
drift_one(undefined, #{p := P, v := V} = B, Dt) -> B#{p := rw_vec:madd(P, V, Dt)};
drift_one(G, #{p := P, v := V} = B, Dt) ->
    B#{p := rw_vec:madd(rw_vec:madd(P, V, Dt), G, 0.5 * Dt * Dt), v := rw_vec:madd(V, G, Dt)}.

collide(#{restitution := E}, {pair, I, J}, Bs) ->
    #{p := PA, v := VA, m := MA} = A = element(I, Bs),
    #{p := PB, v := VB, m := MB} = B = element(J, Bs),
    N = rw_vec:norm(rw_vec:sub(PB, PA)),
    Vn = rw_vec:dot(rw_vec:sub(VB, VA), N),
    Jn = -(1.0 + E) * Vn / (1.0 / MA + 1.0 / MB),
    A1 = maps:remove(resting, A#{v := rw_vec:madd(VA, N, -Jn / MA)}),
    B1 = maps:remove(resting, B#{v := rw_vec:madd(VB, N, Jn / MB)}),
    setelement(J, setelement(I, Bs, A1), B1);
collide(#{restitution := E, planes := Planes, gravity := G}, {plane, I, K}, Bs) ->
    #{v := V} = Body = element(I, Bs),
    N = element(1, lists:nth(K, Planes)),
    Vn = rw_vec:dot(V, N),
    Gn = case G of undefined -> 0.0; _ -> rw_vec:dot(G, N) end,
    case -E * Vn < ?REST_SPEED andalso Gn < 0.0 of
        true ->
            %% the normal velocity goes, the tangential stays; gravity's
            %% tangential part accelerates it along the wall
            Vt = rw_vec:madd(V, N, -Vn),
            setelement(I, Bs, Body#{v := Vt, resting => {K, rw_vec:madd(G, N, -Gn)}});
        false ->
            setelement(I, Bs, Body#{v := rw_vec:madd(V, N, -(1.0 + E) * Vn)})
    end.
