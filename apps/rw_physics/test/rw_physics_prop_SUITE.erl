%% Runs the physics properties (rw_physics_prop) from common_test: one case
%% per prop_*/0, failing with the shrunk counterexample.
-module(rw_physics_prop_SUITE).
-include_lib("common_test/include/ct.hrl").
-export([all/0, suite/0, end_per_testcase/2]).
-export([pair_momentum/1, pair_angular_momentum/1, pair_energy/1, fixture_energy/1, restitution_law/1,
         friction_coulomb/1, pair_symmetric_and_repeatable/1, hash_covers_aabb/1, hash_region_keeps_box/1, normals_unit/1,
         depth_along_normal/1, cylinder_depth_along_normal/1, swept_toi/1, degenerate_input/1,
         quat_integrate/1, free_flight/1, respond_is_ordered_fold/1, container_is_six_walls/1,
         fixture_box_skips_only_misses/1, fixture_then_pair_energy/1, island_equals_all_pairs/1,
         sweep_spheres_equals_all_pairs/1, sweep_spans_equals_all_pairs/1, grid_equals_shared_cells/1]).

%% Tests per property; the whole suite takes a few seconds.
-define(NUMTESTS, 1000).

suite() -> [{timetrap, {minutes, 3}}].

all() -> [pair_momentum, pair_angular_momentum, pair_energy, fixture_energy, restitution_law, friction_coulomb,
          pair_symmetric_and_repeatable, hash_covers_aabb, hash_region_keeps_box, normals_unit, depth_along_normal,
          cylinder_depth_along_normal, swept_toi, degenerate_input, quat_integrate, free_flight,
          respond_is_ordered_fold, container_is_six_walls, fixture_box_skips_only_misses,
          fixture_then_pair_energy, island_equals_all_pairs, sweep_spheres_equals_all_pairs,
          sweep_spans_equals_all_pairs, grid_equals_shared_cells].

end_per_testcase(_Case, _Config) ->
    proper:global_state_erase(),
    ok.

check(Name) ->
    Prop = list_to_atom("prop_" ++ atom_to_list(Name)),
    case proper:quickcheck(rw_physics_prop:Prop(), [{numtests, ?NUMTESTS}, {to_file, user}, long_result]) of
        true ->
            ok;
        Counterexample ->
            ct:pal("~p failed; counterexample:~n~p", [Prop, Counterexample]),
            ct:fail({Prop, Counterexample})
    end.

pair_momentum(_) -> check(pair_momentum).
hash_region_keeps_box(_) -> check(hash_region_keeps_box).
container_is_six_walls(_) -> check(container_is_six_walls).
fixture_box_skips_only_misses(_) -> check(fixture_box_skips_only_misses).
fixture_then_pair_energy(_) -> check(fixture_then_pair_energy).
island_equals_all_pairs(_) -> check(island_equals_all_pairs).
sweep_spheres_equals_all_pairs(_) -> check(sweep_spheres_equals_all_pairs).
sweep_spans_equals_all_pairs(_) -> check(sweep_spans_equals_all_pairs).
grid_equals_shared_cells(_) -> check(grid_equals_shared_cells).
pair_angular_momentum(_) -> check(pair_angular_momentum).
pair_energy(_) -> check(pair_energy).
fixture_energy(_) -> check(fixture_energy).
restitution_law(_) -> check(restitution_law).
friction_coulomb(_) -> check(friction_coulomb).
pair_symmetric_and_repeatable(_) -> check(pair_symmetric_and_repeatable).
hash_covers_aabb(_) -> check(hash_covers_aabb).
normals_unit(_) -> check(normals_unit).
depth_along_normal(_) -> check(depth_along_normal).
cylinder_depth_along_normal(_) -> check(cylinder_depth_along_normal).
swept_toi(_) -> check(swept_toi).
degenerate_input(_) -> check(degenerate_input).
quat_integrate(_) -> check(quat_integrate).
free_flight(_) -> check(free_flight).
respond_is_ordered_fold(_) -> check(respond_is_ordered_fold).
