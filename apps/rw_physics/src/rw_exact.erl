%% An exact, event-driven solver for spheres without rotation or friction,
%% optionally under uniform gravity, against half-space planes: bodies move
%% ballistically between exactly computed times of impact, and each impact
%% applies the restitution impulse along the line of centres. It is the
%% yardstick of `rigidwarp accuracy`: the engines' substepped results are
%% compared with it.
%%
%% Times are in seconds here. A sphere whose bounce off a plane is slower
%% than ?REST_SPEED is put to rest on it (restitution < 1 would otherwise
%% make infinitely many bounces before a finite time).
-module(rw_exact).
-export([run/3, pair_toi/6, plane_toi/6]).
-export_type([body/0, world/0, frame/0]).

-type body() :: #{id := binary(), r := float(), m := float(), p := rw_vec:vec(), v := rw_vec:vec(),
                  resting => non_neg_integer()}.
-type world() :: #{gravity := rw_vec:vec() | undefined, restitution := float(),
                   planes := [{rw_vec:vec(), float()}]}.
-type frame() :: {Tms :: non_neg_integer(), [{binary(), rw_vec:vec(), rw_vec:vec()}]}.

-define(REST_SPEED, 1.0e-9).
-define(MAX_EVENTS, 1000000).

%% The states at each of FrameTimes (ms, ascending) and the impacts that
%% happened: {Frames, Events} with Events = [{Tseconds, What}] in order.
-spec run(world(), [body()], [non_neg_integer()]) -> {[frame()], [{float(), term()}]}.
run(World, Bodies, FrameTimes) ->
    step(World, list_to_tuple(Bodies), 0.0, FrameTimes, [], [], 0).

step(_W, _Bs, _T, [], Frames, Events, _N) ->
    {lists:reverse(Frames), lists:reverse(Events)};
step(_W, _Bs, _T, _Left, _Frames, _Events, N) when N > ?MAX_EVENTS ->
    error(too_many_events);
step(W, Bs, T, [Fms | Rest] = Frames0, Frames, Events, N) ->
    Tf = Fms / 1000,
    case next_event(W, Bs) of
        {Dt, Event} when T + Dt =< Tf ->
            Bs1 = collide(W, Event, drift(W, Bs, Dt)),
            step(W, Bs1, T + Dt, Frames0, Frames, [{T + Dt, Event} | Events], N + 1);
        _ ->
            Bs1 = drift(W, Bs, Tf - T),
            Snapshot = {Fms, [{Id, P, V} || #{id := Id, p := P, v := V} <- tuple_to_list(Bs1)]},
            step(W, Bs1, Tf, Rest, [Snapshot | Frames], Events, N)
    end.

%% The earliest impact from now: {Dt, {pair, I, J} | {plane, I, K}} or none.
next_event(#{planes := Planes} = W, Bs) ->
    N = tuple_size(Bs),
    Pairs = [{Dt, {pair, I, J}}
             || I <- lists:seq(1, N), J <- lists:seq(I + 1, N),
                Dt <- pair_event(element(I, Bs), element(J, Bs))],
    Walls = [{Dt, {plane, I, K}}
             || I <- lists:seq(1, N), not maps:is_key(resting, element(I, Bs)),
                {K, {Nrm, Off}} <- lists:zip(lists:seq(1, length(Planes)), Planes),
                Dt <- plane_event(W, element(I, Bs), Nrm, Off)],
    case lists:sort(Pairs ++ Walls) of
        [] -> none;
        [First | _] -> First
    end.

pair_event(#{p := PA, v := VA, r := RA}, #{p := PB, v := VB, r := RB}) ->
    case pair_toi(PA, VA, RA, PB, VB, RB) of
        none -> [];
        Dt -> [Dt]
    end.

plane_event(#{gravity := G}, #{p := P, v := V, r := R}, N, Off) ->
    case plane_toi(P, V, G, R, N, Off) of
        none -> [];
        Dt -> [Dt]
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

drift(#{gravity := G}, Bs, Dt) ->
    list_to_tuple([drift_one(G, B, Dt) || B <- tuple_to_list(Bs)]).

drift_one(_G, #{resting := _} = B, _Dt) -> B;
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
collide(#{restitution := E, planes := Planes}, {plane, I, K}, Bs) ->
    #{v := V} = Body = element(I, Bs),
    {N, _} = lists:nth(K, Planes),
    Vn = rw_vec:dot(V, N),
    V1 = rw_vec:madd(V, N, -(1.0 + E) * Vn),
    case -E * Vn < ?REST_SPEED of
        true -> setelement(I, Bs, Body#{v := rw_vec:zero(), resting => K});
        false -> setelement(I, Bs, Body#{v := V1})
    end.
