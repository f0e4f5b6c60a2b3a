%% Narrowphase: contacts between spheres, and between a sphere and a static
%% shape, at one instant or swept over one substep. Normals point from the
%% first body to the second (from the sphere to the fixture). Every function
%% is total: degenerate input (coincident centres, zero motion) yields a
%% definite unit normal, never NaN.
-module(rw_narrow).
-include("rw_physics.hrl").
-export([sphere_sphere/4, swept_sphere_sphere/6, sphere_fixture/3, swept_sphere_fixture/4,
         fixture/3, swept_fixture/4, segment_box/5]).
-export_type([feature_contact/0]).

%% A fixture can touch a sphere at several features (a container's walls).
-type feature_contact() :: {Feature :: non_neg_integer(), #contact{}}.

-define(FALLBACK_NORMAL, {0.0, 1.0, 0.0}).
-include("rw_vec_inline.hrl").

-spec sphere_sphere(rw_vec:vec(), float(), rw_vec:vec(), float()) -> #contact{} | none.
sphere_sphere(PA, RA, PB, RB) when is_float(RA), is_float(RB) ->
    D = vsub(PB, PA),
    Sum = RA + RB,
    L2 = vlen2(D),
    case L2 < Sum * Sum of
        false -> none;
        true ->
            L = math:sqrt(L2),
            N = case L > 0.0 of
                    true -> vscale(D, 1.0 / L);
                    false -> ?FALLBACK_NORMAL
                end,
            #contact{n = N, depth = Sum - L, toi = 0.0}
    end.

%% Spheres at PA and PB moving by DA and DB over the substep: overlapping
%% now, or first touching at fraction Toi of the substep.
-spec swept_sphere_sphere(rw_vec:vec(), rw_vec:vec(), float(), rw_vec:vec(), rw_vec:vec(), float()) ->
          #contact{} | none.
swept_sphere_sphere(PA, DA, RA, PB, DB, RB) ->
    case sphere_sphere(PA, RA, PB, RB) of
        none ->
            X0 = vsub(PB, PA),
            DR = vsub(DB, DA),
            Sum = RA + RB,
            A = vlen2(DR),
            B = 2.0 * vdot(X0, DR),
            C = vlen2(X0) - Sum * Sum,
            Disc = B * B - 4.0 * A * C,
            case A > 0.0 andalso B < 0.0 andalso Disc >= 0.0 of
                false -> none;
                true ->
                    S = (-B - math:sqrt(Disc)) / (2.0 * A),
                    case S >= 0.0 andalso S =< 1.0 of
                        false -> none;
                        true ->
                            N = unit_or_fallback(vmadd(X0, DR, S)),
                            #contact{n = N, depth = Sum - math:sqrt(vlen2(X0)), toi = S}
                    end
            end;
        Contact ->
            Contact
    end.

-spec sphere_fixture(rw_vec:vec(), float(), rw_shape:static_shape()) -> [feature_contact()].
sphere_fixture(P, R, {plane, N, Off}) when is_float(R), is_float(Off) ->
    Depth = R - (vdot(N, P) - Off),
    case Depth > 0.0 of
        true -> [{0, #contact{n = vneg(N), depth = Depth}}];
        false -> []
    end;
sphere_fixture({PX, PY, PZ} = P, R, {box, {CX, CY, CZ} = C, {EX, EY, EZ} = E, hollow})
  when ?IS_VEC(PX, PY, PZ), ?IS_VEC(CX, CY, CZ), ?IS_VEC(EX, EY, EZ), is_float(R) ->
    %% Most substeps a sphere is well inside its container: test the six
    %% depths as walls/4 computes them (a unit normal's dot product is the
    %% coordinate itself) before building any contact.
    case R - (PX - (CX - EX)) > 0.0 orelse R - (-PX + (CX + EX)) > 0.0 orelse
         R - (PY - (CY - EY)) > 0.0 orelse R - (-PY + (CY + EY)) > 0.0 orelse
         R - (PZ - (CZ - EZ)) > 0.0 orelse R - (-PZ + (CZ + EZ)) > 0.0 of
        true -> walls(P, R, C, E);
        false -> []
    end;
sphere_fixture(P, R, {box, C, E, solid}) ->
    solid_box(P, R, C, E);
sphere_fixture(P, R, {cylinder, C, Axis, CR, H}) ->
    cylinder(P, R, C, Axis, CR, H).

%% The same against a fixture with its bounding box: a sphere farther than
%% its radius outside the box is rejected without testing the shape (every
%% body tests every fixture at every substep, and most are far away).
-spec fixture(rw_vec:vec(), float(), #fixture{}) -> [feature_contact()].
fixture(P, R, #fixture{shape = Shape, box = unbounded}) ->
    sphere_fixture(P, R, Shape);
fixture({X, Y, Z} = P, R, #fixture{shape = Shape, box = {X0, Y0, Z0, X1, Y1, Z1}})
  when ?IS_VEC(X, Y, Z), is_float(R), ?IS_VEC(X0, Y0, Z0), ?IS_VEC(X1, Y1, Z1) ->
    case X + R < X0 orelse X - R > X1 orelse Y + R < Y0 orelse Y - R > Y1 orelse
         Z + R < Z0 orelse Z - R > Z1 of
        true -> [];
        false -> sphere_fixture(P, R, Shape)
    end.

%% Swept: the box of the whole path must miss it.
-spec swept_fixture(rw_vec:vec(), rw_vec:vec(), float(), #fixture{}) -> [feature_contact()].
swept_fixture(P, D, R, #fixture{shape = Shape, box = unbounded}) ->
    swept_sphere_fixture(P, D, R, Shape);
swept_fixture({X, Y, Z} = P, {DX, DY, DZ} = D, R, #fixture{shape = Shape, box = {X0, Y0, Z0, X1, Y1, Z1}}) ->
    case max(X, X + DX) + R < X0 orelse min(X, X + DX) - R > X1 orelse
         max(Y, Y + DY) + R < Y0 orelse min(Y, Y + DY) - R > Y1 orelse
         max(Z, Z + DZ) + R < Z0 orelse min(Z, Z + DZ) - R > Z1 of
        true -> [];
        false -> swept_sphere_fixture(P, D, R, Shape)
    end.

%% Sphere at P moving by D during the substep.
-spec swept_sphere_fixture(rw_vec:vec(), rw_vec:vec(), float(), rw_shape:static_shape()) ->
          [feature_contact()].
swept_sphere_fixture(P, D, R, {plane, N, Off} = Shape) ->
    case sphere_fixture(P, R, Shape) of
        [] -> swept_half_space(0, P, D, R, N, Off);
        Hit -> Hit
    end;
swept_sphere_fixture(P, D, R, {box, C, E, hollow}) ->
    %% each wall is a half-space whose inside faces the box centre
    lists:append(
      [case overlapping_wall(F, P, R, C, E) of
           [] ->
               {N, Off} = wall_plane(F, C, E),
               swept_half_space(F, P, D, R, N, Off);
           Hit -> Hit
       end || F <- [0, 1, 2, 3, 4, 5]]);
swept_sphere_fixture(P, D, R, {box, C, E, solid}) ->
    case solid_box(P, R, C, E) of
        [] -> swept_box(P, D, R, C, E);
        Hit -> Hit
    end;
swept_sphere_fixture(P, D, R, {cylinder, C, Axis, CR, H}) ->
    case cylinder(P, R, C, Axis, CR, H) of
        [] -> swept_by_samples(P, D, R, fun(Q) -> cylinder(Q, R, C, Axis, CR, H) end);
        Hit -> Hit
    end.

%% Slab test: where the segment P + t D, t in [0, 1], enters the box from Lo
%% to Hi: {TEnter, Axis}, Axis (0, 1 or 2) naming the slab it entered last
%% (none when it starts inside every slab), or none when it misses. A closed
%% box counts its surface (a segment that touches it meets it), an open box
%% only its inside.
-spec segment_box(rw_vec:vec(), rw_vec:vec(), rw_vec:vec(), rw_vec:vec(), closed | open) ->
          {float(), 0..2 | none} | none.
segment_box(P, D, Lo, Hi, Kind) -> slabs(0, P, D, Lo, Hi, 0.0, 1.0, none, Kind).

%%% Internals

unit_or_fallback(V) ->
    L = vlen(V),
    case L > 0.0 of
        true -> vscale(V, 1.0 / L);
        false -> ?FALLBACK_NORMAL
    end.

%% A solid half-space {x | N.x < Off}, the sphere on the outside moving by D.
swept_half_space(F, P, D, R, N, Off) ->
    Gap = vdot(N, P) - Off - R,
    Dn = vdot(N, D),
    case Gap >= 0.0 andalso Dn < 0.0 andalso Gap + Dn =< 0.0 of
        true -> [{F, #contact{n = vneg(N), depth = -Gap, toi = Gap / -Dn}}];
        false -> []
    end.

%% Wall F of a container (2*axis for the lower wall, 2*axis+1 for the upper)
%% as the half-space plane {x | N.x >= Off} with N pointing into the box.
wall_plane(F, C, E) ->
    Axis = F div 2,
    Ci = element(Axis + 1, C),
    Ei = element(Axis + 1, E),
    case F rem 2 of
        0 -> {unit(Axis, 1.0), Ci - Ei};
        1 -> {unit(Axis, -1.0), -(Ci + Ei)}
    end.

overlapping_wall(F, P, R, C, E) ->
    {N, Off} = wall_plane(F, C, E),
    Depth = R - (vdot(N, P) - Off),
    case Depth > 0.0 of
        true -> [{F, #contact{n = vneg(N), depth = Depth}}];
        false -> []
    end.

walls(P, R, C, E) ->
    lists:append([overlapping_wall(F, P, R, C, E) || F <- [0, 1, 2, 3, 4, 5]]).

unit(0, S) -> {S, 0.0, 0.0};
unit(1, S) -> {0.0, S, 0.0};
unit(2, S) -> {0.0, 0.0, S}.

solid_box({PX, PY, PZ} = P, R, {CX, CY, CZ} = C, {EX, EY, EZ} = E) ->
    Closest = {clamp(PX, CX - EX, CX + EX), clamp(PY, CY - EY, CY + EY), clamp(PZ, CZ - EZ, CZ + EZ)},
    case Closest =:= P of
        true ->
            %% centre inside: leave through the nearest face
            Rel = vsub(P, C),
            Slack = [{element(I + 1, E) - abs(element(I + 1, Rel)), I} || I <- [0, 1, 2]],
            {S, I} = lists:min(Slack),
            Sign = case element(I + 1, Rel) >= 0.0 of true -> -1.0; false -> 1.0 end,
            [{0, #contact{n = unit(I, Sign), depth = R + S}}];
        false ->
            point_contact(P, R, Closest)
    end.

point_contact(P, R, Closest) when is_float(R) ->
    D = vsub(Closest, P),
    L2 = vlen2(D),
    case L2 < R * R of
        true ->
            L = math:sqrt(L2),
            [{0, #contact{n = vscale(D, 1.0 / L), depth = R - L}}];
        false ->
            []
    end.

clamp(X, Lo, Hi) -> max(Lo, min(Hi, X)).

cylinder(P, R, C, Axis, CR, H) when is_float(R), is_float(CR), is_float(H) ->
    Rel = vsub(P, C),
    H0 = vdot(Rel, Axis),
    Radial = vmadd(Rel, Axis, -H0),
    RL = vlen(Radial),
    case abs(H0) =< H andalso RL =< CR of
        true ->
            Side = CR - RL,
            Cap = H - abs(H0),
            case Side < Cap of
                true ->
                    %% on a tilted axis the radial offset of a centre on the axis is
                    %% rounding noise: treat it as on the axis
                    N = case RL > 1.0e-12 * max(vlen(Rel), CR) of
                            true -> vscale(Radial, -1.0 / RL);
                            false -> any_perpendicular(Axis)
                        end,
                    [{0, #contact{n = N, depth = R + Side}}];
                false ->
                    Sign = case H0 >= 0.0 of true -> -1.0; false -> 1.0 end,
                    [{0, #contact{n = vscale(Axis, Sign), depth = R + Cap}}]
            end;
        false when RL > (CR + R) * (1.0 + 1.0e-9); abs(H0) > (H + R) * (1.0 + 1.0e-9) ->
            %% farther than R from the side or beyond the caps (with a margin
            %% far above rounding): no contact, without finding the closest point
            [];
        false ->
            HC = clamp(H0, -H, H),
            RadialC = case RL > CR of
                          true -> vscale(Radial, CR / RL);
                          false -> Radial
                      end,
            Closest = vadd(vmadd(C, Axis, HC), RadialC),
            point_contact(P, R, Closest)
    end.

any_perpendicular({AX, _, _} = Axis) ->
    Other = case abs(AX) < 0.9 of true -> {1.0, 0.0, 0.0}; false -> {0.0, 1.0, 0.0} end,
    rw_vec:norm(vcross(Axis, Other)).

%% Segment P -> P+D against the box grown by R (slab test). Conservative at
%% edges and corners, where the grown box is larger than the rounded one.
swept_box(P, D, R, C, E) ->
    Lo = vsub(vsub(C, E), {R, R, R}),
    Hi = vadd(vadd(C, E), {R, R, R}),
    case segment_box(P, D, Lo, Hi, closed) of
        {TEnter, Axis} when TEnter > 0.0 ->
            Sign = case element(Axis + 1, D) > 0.0 of true -> 1.0; false -> -1.0 end,
            Gap = slab_gap(P, C, E, R),
            [{0, #contact{n = unit(Axis, Sign), depth = -Gap, toi = TEnter}}];
        _ ->
            []
    end.

slabs(3, _P, _D, _Lo, _Hi, TMin, TMax, Axis, Kind) ->
    case nonempty(TMin, TMax, Kind) of
        true -> {TMin, Axis};
        false -> none
    end;
slabs(I, P, D, Lo, Hi, TMin, TMax, Axis, Kind) ->
    Pi = element(I + 1, P), Di = element(I + 1, D),
    Li = element(I + 1, Lo), Hi_ = element(I + 1, Hi),
    case Di == 0.0 of
        true ->
            case within(Pi, Li, Hi_, Kind) of
                true -> slabs(I + 1, P, D, Lo, Hi, TMin, TMax, Axis, Kind);
                false -> none
            end;
        false ->
            T1 = (Li - Pi) / Di, T2 = (Hi_ - Pi) / Di,
            {TNear, TFar} = {min(T1, T2), max(T1, T2)},
            {TMin2, Axis2} = case TNear > TMin of
                                 true -> {TNear, I};
                                 false -> {TMin, Axis}
                             end,
            TMax2 = min(TMax, TFar),
            case nonempty(TMin2, TMax2, Kind) of
                true -> slabs(I + 1, P, D, Lo, Hi, TMin2, TMax2, Axis2, Kind);
                false -> none
            end
    end.

nonempty(TMin, TMax, closed) -> TMin =< TMax;
nonempty(TMin, TMax, open) -> TMin < TMax.

within(X, Lo, Hi, closed) -> X >= Lo andalso X =< Hi;
within(X, Lo, Hi, open) -> X > Lo andalso X < Hi.

slab_gap({PX, PY, PZ}, {CX, CY, CZ}, {EX, EY, EZ}, R) ->
    Closest = {clamp(PX, CX - EX, CX + EX), clamp(PY, CY - EY, CY + EY), clamp(PZ, CZ - EZ, CZ + EZ)},
    vlen(vsub(Closest, {PX, PY, PZ})) - R.

%% Shapes without a closed-form swept test are sampled along the path at
%% steps of a quarter radius (at most 256 samples).
swept_by_samples(P, D, R, Test) ->
    Len = vlen(D),
    N = min(256, max(1, ceil(Len / (0.25 * R)))),
    sample(1, N, P, D, Test).

sample(I, N, _P, _D, _Test) when I > N -> [];
sample(I, N, P, D, Test) ->
    S = I / N,
    case Test(vmadd(P, D, S)) of
        [] -> sample(I + 1, N, P, D, Test);
        Hits -> [{F, C#contact{depth = 0.0, toi = S}} || {F, C} <- Hits]
    end.
