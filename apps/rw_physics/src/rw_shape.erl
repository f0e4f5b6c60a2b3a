%% Static shapes (fixtures) and bounding boxes. Dynamic bodies are spheres;
%% their properties live in #sphere{} (see rw_physics.hrl).
-module(rw_shape).
-include("rw_physics.hrl").
-export([sphere/4, inertia_inv/2, sphere_aabb/2, swept_aabb/3, fixture_aabb/1, fixture/3]).
-export_type([static_shape/0, aabb/0, box6/0]).

-type static_shape() ::
        {plane, Normal :: rw_vec:vec(), Offset :: float()}
      | {cylinder, Centre :: rw_vec:vec(), Axis :: rw_vec:vec(), Radius :: float(), HalfLength :: float()}
      | {box, Centre :: rw_vec:vec(), HalfExtents :: rw_vec:vec(), solid | hollow}.
-type aabb() :: {Min :: rw_vec:vec(), Max :: rw_vec:vec()}.
%% A box as six numbers, flat for hot comparisons: a fixture's bounding box,
%% the box of a body's packed states (rw_states:extents()) and of a write to
%% the TVHT (rw_bucket:bounds()).
-type box6() :: {X0 :: float(), Y0 :: float(), Z0 :: float(), X1 :: float(), Y1 :: float(), Z1 :: float()}.

%% A fixture with its bounding box. The box is padded far beyond rounding
%% (1e-9 of its size and distance from the origin), so a sphere outside it
%% by more than its radius is certainly not touching the shape.
-spec fixture(non_neg_integer(), binary(), static_shape()) -> #fixture{}.
fixture(Idx, Id, Shape) ->
    Box = case fixture_aabb(Shape) of
              unbounded -> unbounded;
              {{X0, Y0, Z0}, {X1, Y1, Z1}} ->
                  Pad = 1.0e-9 * (1.0 + lists:max([abs(X) || X <- [X0, Y0, Z0, X1, Y1, Z1]])),
                  {X0 - Pad, Y0 - Pad, Z0 - Pad, X1 + Pad, Y1 + Pad, Z1 + Pad}
          end,
    #fixture{idx = Idx, id = Id, shape = Shape, box = Box}.

-spec sphere(non_neg_integer(), binary(), float(), float()) -> #sphere{}.
sphere(Idx, Id, Radius, Mass) ->
    #sphere{idx = Idx, id = Id, radius = Radius, mass = Mass, inv_mass = 1.0 / Mass,
            inv_inertia = inertia_inv(Radius, Mass)}.

%% Inverse moment of inertia of a solid sphere, 1 / (2/5 m r^2).
-spec inertia_inv(float(), float()) -> float().
inertia_inv(Radius, Mass) -> 2.5 / (Mass * Radius * Radius).

-spec sphere_aabb(rw_vec:vec(), float()) -> aabb().
sphere_aabb({X, Y, Z}, R) -> {{X - R, Y - R, Z - R}, {X + R, Y + R, Z + R}}.

%% Box around a sphere moving by D during a substep (for swept tests).
-spec swept_aabb(rw_vec:vec(), rw_vec:vec(), float()) -> aabb().
swept_aabb({X, Y, Z}, {DX, DY, DZ}, R) ->
    {{min(X, X + DX) - R, min(Y, Y + DY) - R, min(Z, Z + DZ) - R},
     {max(X, X + DX) + R, max(Y, Y + DY) + R, max(Z, Z + DZ) + R}}.

%% Bounded fixtures have a box; planes and containers are unbounded.
-spec fixture_aabb(static_shape()) -> aabb() | unbounded.
fixture_aabb({plane, _, _}) -> unbounded;
fixture_aabb({box, _, _, hollow}) -> unbounded;
fixture_aabb({box, C, E, solid}) -> {rw_vec:sub(C, E), rw_vec:add(C, E)};
fixture_aabb({cylinder, C, {AX, AY, AZ}, R, H}) ->
    %% extent of a capped cylinder along each world axis
    Ext = {H * abs(AX) + R * math:sqrt(max(0.0, 1.0 - AX * AX)),
           H * abs(AY) + R * math:sqrt(max(0.0, 1.0 - AY * AY)),
           H * abs(AZ) + R * math:sqrt(max(0.0, 1.0 - AZ * AZ))},
    {rw_vec:sub(C, Ext), rw_vec:add(C, Ext)}.
