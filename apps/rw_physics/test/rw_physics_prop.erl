%% PropEr properties of the pure physics (run by rw_physics_prop_SUITE).
-module(rw_physics_prop).
-include_lib("proper/include/proper.hrl").
-include("rw_physics.hrl").
-export([prop_pair_conserves_momentum/0, prop_pair_energy/0, prop_pair_symmetric_and_repeatable/0,
         prop_angular_momentum/0, prop_hash_covers_aabb/0, prop_normals_unit/0,
         prop_degenerate_input/0, prop_quat_unit/0, prop_free_flight/0, prop_respond_is_ordered_sum/0]).

-define(TOL, 1.0e-9).

%%% Generators

coord() -> range_float(-100.0, 100.0).
range_float(Lo, Hi) -> ?LET(X, float(Lo, Hi), X).
vec() -> {coord(), coord(), coord()}.
small_vec() -> {range_float(-10.0, 10.0), range_float(-10.0, 10.0), range_float(-10.0, 10.0)}.
unit_vec() -> ?SUCHTHAT(V, small_vec(), rw_vec:len(V) > 1.0e-3).

sphere(Idx) -> ?LET({R, M}, {range_float(0.05, 2.0), oneof([range_float(0.01, 100.0), 1.0, 1.0e6])},
                    rw_shape:sphere(Idx, integer_to_binary(Idx), R, M)).

model() ->
    ?LET({E, Mu, Rot}, {oneof([0.0, 1.0, range_float(0.0, 1.0)]), oneof([undefined, range_float(0.0, 1.0)]), boolean()},
         #model{dt = 0.001, restitution = E, friction = Mu, rotation = Rot, rest_speed = 0.0}).

state(#model{rotation = Rot}) ->
    ?LET({P, V, W}, {vec(), small_vec(), small_vec()},
         case Rot of
             true -> #st{p = P, v = V, q = rw_quat:identity(), w = W};
             false -> #st{p = P, v = V}
         end).

%% Two spheres in contact: B placed along a random direction from A at a
%% distance a little less than the sum of radii.
touching_pair() ->
    ?LET({M, SA, SB, Dir, Overlap}, {model(), sphere(0), sphere(1), unit_vec(), range_float(0.0, 0.05)},
         ?LET({StA, StB0}, {state(M), state(M)},
              begin
                  #sphere{radius = RA} = SA, #sphere{radius = RB} = SB,
                  Dist = (RA + RB) * (1.0 - Overlap),
                  StB = StB0#st{p = rw_vec:madd(StA#st.p, rw_vec:norm(Dir), Dist)},
                  {M, SA, StA, SB, StB}
              end)).

%%% Helpers

with(Contact, {M, SA, StA, SB, StB}) ->
    rw_response:pair(M, SA, StA, SB, StB, Contact).

momentum(#sphere{mass = M}, V) -> rw_vec:scale(V, M).

close(A, B, Scale) -> abs(A - B) =< ?TOL * max(1.0, Scale).

ke(#sphere{mass = M, radius = R}, V, undefined) -> 0.5 * M * rw_vec:len2(V) + 0.0 * R;
ke(#sphere{mass = M, radius = R}, V, W) -> 0.5 * M * rw_vec:len2(V) + 0.5 * (0.4 * M * R * R) * rw_vec:len2(W).

add(undefined, _) -> undefined;
add(W, Dw) -> rw_vec:add(W, Dw).

%%% Properties

prop_pair_conserves_momentum() ->
    ?FORALL({M, SA, StA, SB, StB} = Pair, touching_pair(),
            begin
                Contact = rw_narrow:sphere_sphere(StA#st.p, SA#sphere.radius, StB#st.p, SB#sphere.radius),
                {{DvA, _, _}, {DvB, _, _}} = with(Contact, Pair),
                Sum = rw_vec:add(momentum(SA, DvA), momentum(SB, DvB)),
                Scale = rw_vec:len(momentum(SA, DvA)) + 1.0,
                _ = M,
                ?WHENFAIL(io:format("dpA + dpB = ~p~n", [Sum]), rw_vec:len(Sum) =< ?TOL * Scale * 10)
            end).

%% One contact's impulse: energy kept at restitution 1 without friction,
%% never gained otherwise.
prop_pair_energy() ->
    ?FORALL({M, SA, StA, SB, StB} = Pair, touching_pair(),
            begin
                Contact = rw_narrow:sphere_sphere(StA#st.p, SA#sphere.radius, StB#st.p, SB#sphere.radius),
                {{DvA, DwA, _}, {DvB, DwB, _}} = with(Contact, Pair),
                Before = ke(SA, StA#st.v, StA#st.w) + ke(SB, StB#st.v, StB#st.w),
                After = ke(SA, rw_vec:add(StA#st.v, DvA), add(StA#st.w, DwA)) +
                        ke(SB, rw_vec:add(StB#st.v, DvB), add(StB#st.w, DwB)),
                Elastic = M#model.restitution =:= 1.0 andalso M#model.friction =:= undefined,
                ?WHENFAIL(io:format("KE ~p -> ~p (model ~p)~n", [Before, After, M]),
                          case Elastic of
                              true -> close(Before, After, Before);
                              false -> After =< Before * (1.0 + ?TOL) + ?TOL
                          end)
            end).

prop_pair_symmetric_and_repeatable() ->
    ?FORALL({_M, SA, StA, SB, StB} = Pair, touching_pair(),
            begin
                Contact = rw_narrow:sphere_sphere(StA#st.p, SA#sphere.radius, StB#st.p, SB#sphere.radius),
                {{DvA, _, _}, {DvB, _, _}} = R1 = with(Contact, Pair),
                R2 = with(Contact, Pair),
                %% equal and opposite impulses
                JA = momentum(SA, DvA), JB = momentum(SB, DvB),
                R1 =:= R2 andalso rw_vec:len(rw_vec:add(JA, JB)) =< ?TOL * (rw_vec:len(JA) + 1.0) * 10
            end).

%% With rotation and friction, angular momentum about the origin
%% (r x m v + I w, summed over both bodies) is kept by a pair impulse.
prop_angular_momentum() ->
    ?FORALL({M0, SA, StA, SB, StB}, touching_pair(),
            begin
                M = M0#model{rotation = true, friction = 0.5},
                StA1 = StA#st{q = rw_quat:identity(), w = case StA#st.w of undefined -> {1.0, 0.0, 0.0}; W -> W end},
                StB1 = StB#st{q = rw_quat:identity(), w = case StB#st.w of undefined -> {0.0, 2.0, 0.0}; W2 -> W2 end},
                Contact = rw_narrow:sphere_sphere(StA1#st.p, SA#sphere.radius, StB1#st.p, SB#sphere.radius),
                {{DvA, DwA, _}, {DvB, DwB, _}} = rw_response:pair(M, SA, StA1, SB, StB1, Contact),
                %% impulses act at the contact point, on the line between the centres
                L = fun(#sphere{mass = Ms, radius = R}, #st{p = P}, V, W) ->
                            rw_vec:add(rw_vec:cross(P, rw_vec:scale(V, Ms)), rw_vec:scale(W, 0.4 * Ms * R * R))
                    end,
                Before = rw_vec:add(L(SA, StA1, StA1#st.v, StA1#st.w), L(SB, StB1, StB1#st.v, StB1#st.w)),
                After = rw_vec:add(L(SA, StA1, rw_vec:add(StA1#st.v, DvA), rw_vec:add(StA1#st.w, DwA)),
                                   L(SB, StB1, rw_vec:add(StB1#st.v, DvB), rw_vec:add(StB1#st.w, DwB))),
                Diff = rw_vec:len(rw_vec:sub(After, Before)),
                %% the contact point is A's surface point; B's lever arm
                %% reaches the same point only up to the overlap depth
                #contact{depth = Depth} = Contact,
                Impulse = rw_vec:len(rw_vec:scale(DvA, SA#sphere.mass)),
                ?WHENFAIL(io:format("angular momentum changed by ~p~n", [Diff]),
                          Diff =< Impulse * Depth + 1.0e-6 * (rw_vec:len(Before) + 1.0))
            end).

prop_hash_covers_aabb() ->
    ?FORALL({Base, Ext, Cell, Far, Fracs, N},
            {vec(), {range_float(0.0, 5.0), range_float(0.0, 5.0), range_float(0.0, 5.0)},
             oneof([0.5, 1.0, 3.7]), oneof([0.0, 1.0e9, -1.0e9, 1.0e11]),
             {float(0.0, 1.0), float(0.0, 1.0), float(0.0, 1.0)}, range(1, 97)},
            begin
                Min = rw_vec:add(Base, {Far, Far, Far}),
                Max = rw_vec:add(Min, Ext),
                Cells = rw_hash:cells({Min, Max}, Cell),
                {FX, FY, FZ} = Fracs, {EX, EY, EZ} = Ext,
                Point = rw_vec:add(Min, {FX * EX, FY * EY, FZ * EZ}),
                lists:member(rw_hash:cell_of(Point, Cell), Cells)
                    andalso lists:member(rw_hash:cell_of(Min, Cell), Cells)
                    andalso lists:member(rw_hash:cell_of(Max, Cell), Cells)
                    andalso Cells =:= lists:usort(Cells)
                    andalso lists:all(fun(C) -> B = rw_hash:bucket(C, N), B >= 0 andalso B < N end, Cells)
            end).

fixture() ->
    oneof([?LET({N, Off}, {unit_vec(), coord()}, {plane, rw_vec:norm(N), Off}),
           ?LET({C, A, R, H}, {vec(), unit_vec(), range_float(0.1, 3.0), range_float(0.1, 5.0)},
                {cylinder, C, rw_vec:norm(A), R, H}),
           ?LET({C, E, Kind}, {vec(), {range_float(0.1, 5.0), range_float(0.1, 5.0), range_float(0.1, 5.0)},
                               oneof([solid, hollow])}, {box, C, E, Kind})]).

unit_and_finite(#contact{n = N, depth = D, toi = T}) ->
    is_float(D) andalso is_float(T) andalso rw_vec:is_finite(N) andalso abs(rw_vec:len(N) - 1.0) =< ?TOL.

prop_normals_unit() ->
    ?FORALL({P, D, R, Q, E, Shape}, {vec(), small_vec(), range_float(0.05, 3.0), vec(), small_vec(), fixture()},
            begin
                Pairs = [C || C <- [rw_narrow:sphere_sphere(P, R, Q, R), rw_narrow:sphere_sphere(P, R, rw_vec:madd(P, D, 0.1), R),
                                    rw_narrow:swept_sphere_sphere(P, D, R, Q, E, R)], C =/= none],
                Fixed = [C || {_, C} <- rw_narrow:sphere_fixture(P, R, Shape) ++
                                        rw_narrow:swept_sphere_fixture(P, D, R, Shape)],
                lists:all(fun unit_and_finite/1, Pairs ++ Fixed)
            end).

prop_degenerate_input() ->
    ?FORALL({P, R, Shape}, {vec(), range_float(0.05, 3.0), fixture()},
            begin
                Same = rw_narrow:sphere_sphere(P, R, P, R),
                Swept = rw_narrow:swept_sphere_sphere(P, {0.0, 0.0, 0.0}, R, P, {0.0, 0.0, 0.0}, R),
                Centre = case Shape of
                             {plane, N, Off} -> rw_vec:scale(N, Off);
                             {cylinder, C, _, _, _} -> C;
                             {box, C, _, _} -> C
                         end,
                AtCentre = rw_narrow:sphere_fixture(Centre, R, Shape) ++
                           rw_narrow:swept_sphere_fixture(Centre, {0.0, 0.0, 0.0}, R, Shape),
                M = #model{dt = 0.001, rotation = true, friction = 0.3},
                S = rw_shape:sphere(0, <<"a">>, R, 1.0),
                St = #st{p = P, v = {0.0, 0.0, 0.0}, q = rw_quat:identity(), w = {0.0, 0.0, 0.0}},
                Effects = [rw_response:fixture(M, S, St, C) || {_, C} <- AtCentre] ++
                          [element(1, rw_response:pair(M, S, St, S, St, Same))],
                unit_and_finite(Same) andalso unit_and_finite(Swept)
                    andalso lists:all(fun({_, C}) -> unit_and_finite(C) end, AtCentre)
                    andalso lists:all(fun({Dv, Dw, Du}) -> rw_vec:is_finite(Dv) andalso rw_vec:is_finite(Dw)
                                                               andalso rw_vec:is_finite(Du) end, Effects)
            end).

prop_quat_unit() ->
    ?FORALL({W, Steps}, {small_vec(), range(1, 200)},
            begin
                Q = lists:foldl(fun(_, Acc) -> rw_quat:integrate(Acc, W, 0.01) end, rw_quat:identity(),
                                lists:seq(1, Steps)),
                {V, S} = Q,
                abs(math:sqrt(rw_vec:len2(V) + S * S) - 1.0) =< 1.0e-12
            end).

prop_free_flight() ->
    ?FORALL({P, V, Int}, {vec(), small_vec(), oneof(rw_integrate:integrators())},
            begin
                M = #model{dt = 0.004, integrator = Int},
                #st{p = P1, v = V1} = rw_integrate:advance(M, #st{p = P, v = V}, V, undefined, rw_vec:zero()),
                P1 =:= rw_vec:madd(P, V, 0.004) andalso V1 =:= V
            end).

prop_respond_is_ordered_sum() ->
    ?FORALL({V, Dvs}, {small_vec(), list({small_vec(), small_vec()})},
            begin
                Effects = [{Dv, undefined, Du} || {Dv, Du} <- Dvs],
                {V1, undefined, U1} = rw_dynamics:respond(#st{p = rw_vec:zero(), v = V}, Effects),
                V1 =:= lists:foldl(fun({Dv, _}, Acc) -> rw_vec:add(Acc, Dv) end, V, Dvs)
                    andalso U1 =:= lists:foldl(fun({_, Du}, Acc) -> rw_vec:add(Acc, Du) end, rw_vec:zero(), Dvs)
            end).
