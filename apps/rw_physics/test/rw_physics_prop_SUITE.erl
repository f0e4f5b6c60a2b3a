%% Runs the physics properties (rw_physics_prop) from common_test.
-module(rw_physics_prop_SUITE).
-include_lib("common_test/include/ct.hrl").
-export([all/0, suite/0]).
-export([pair_conserves_momentum/1, pair_energy/1, pair_symmetric_and_repeatable/1, angular_momentum/1,
         hash_covers_aabb/1, normals_unit/1, degenerate_input/1, quat_unit/1, free_flight/1,
         respond_is_ordered_sum/1]).

suite() -> [{timetrap, {minutes, 3}}].

all() -> [pair_conserves_momentum, pair_energy, pair_symmetric_and_repeatable, angular_momentum,
          hash_covers_aabb, normals_unit, degenerate_input, quat_unit, free_flight, respond_is_ordered_sum].

check(Prop) ->
    case proper:quickcheck(rw_physics_prop:Prop(), [{numtests, 1000}, {to_file, user}, long_result]) of
        true -> ok;
        Failure -> ct:fail({property_failed, Prop, Failure})
    end.

pair_conserves_momentum(_) -> check(prop_pair_conserves_momentum).
pair_energy(_) -> check(prop_pair_energy).
pair_symmetric_and_repeatable(_) -> check(prop_pair_symmetric_and_repeatable).
angular_momentum(_) -> check(prop_angular_momentum).
hash_covers_aabb(_) -> check(prop_hash_covers_aabb).
normals_unit(_) -> check(prop_normals_unit).
degenerate_input(_) -> check(prop_degenerate_input).
quat_unit(_) -> check(prop_quat_unit).
free_flight(_) -> check(prop_free_flight).
respond_is_ordered_sum(_) -> check(prop_respond_is_ordered_sum).
