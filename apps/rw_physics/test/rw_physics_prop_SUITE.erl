%% Runs the physics properties (rw_physics_prop) from common_test: one case
%% per prop_*/0, failing with the shrunk counterexample.
-module(rw_physics_prop_SUITE).
-include_lib("common_test/include/ct.hrl").
-export([all/0, suite/0, end_per_testcase/2]).
-export([pair_momentum/1, pair_angular_momentum/1, pair_energy/1, fixture_energy/1, restitution_law/1,
         friction_coulomb/1, pair_symmetric_and_repeatable/1, hash_covers_aabb/1, hash_region_keeps_box/1, normals_unit/1,
         depth_along_normal/1, cylinder_depth_along_normal/1, swept_toi/1, degenerate_input/1,
         quat_integrate/1, free_flight/1, respond_is_ordered_fold/1, container_is_six_walls/1,
         fixture_box_skips_only_misses/1, fixture_then_pair_energy/1, fixtures_together_energy/1,
         island_equals_all_pairs/1,
         sweep_spheres_equals_all_pairs/1, sweep_spans_equals_all_pairs/1, grid_equals_shared_cells/1,
         swept_cells_cover_the_move/1, swept_contacts_share_a_cell/1, ccd_keeps_sphere_in_container/1,
         island_mutants_are_caught/1]).

%% Tests per property; the whole suite takes a few seconds.
-define(NUMTESTS, 1000).
%% Cases a mutant of the island may survive (each is usually caught well
%% before), in up to three rounds: the cases are random, and the rarest
%% mutant (full_skin) slipped through one round of 3000 now and then.
-define(MUTANT_TESTS, 3000).
-define(MUTANT_ROUNDS, 3).

suite() -> [{timetrap, {minutes, 3}}].

all() -> [pair_momentum, pair_angular_momentum, pair_energy, fixture_energy, restitution_law, friction_coulomb,
          pair_symmetric_and_repeatable, hash_covers_aabb, hash_region_keeps_box, normals_unit, depth_along_normal,
          cylinder_depth_along_normal, swept_toi, degenerate_input, quat_integrate, free_flight,
          respond_is_ordered_fold, container_is_six_walls, fixture_box_skips_only_misses,
          fixture_then_pair_energy, fixtures_together_energy, island_equals_all_pairs, sweep_spheres_equals_all_pairs,
          sweep_spans_equals_all_pairs, grid_equals_shared_cells, swept_cells_cover_the_move,
          swept_contacts_share_a_cell, ccd_keeps_sphere_in_container, island_mutants_are_caught].

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
fixtures_together_energy(_) -> check(fixtures_together_energy).
island_equals_all_pairs(_) -> check(island_equals_all_pairs).
sweep_spheres_equals_all_pairs(_) -> check(sweep_spheres_equals_all_pairs).
sweep_spans_equals_all_pairs(_) -> check(sweep_spans_equals_all_pairs).
grid_equals_shared_cells(_) -> check(grid_equals_shared_cells).
swept_cells_cover_the_move(_) -> check(swept_cells_cover_the_move).
swept_contacts_share_a_cell(_) -> check(swept_contacts_share_a_cell).
ccd_keeps_sphere_in_container(_) -> check(ccd_keeps_sphere_in_container).

%% The island property can fail where it matters: each mutation below of
%% rw_island's validity rules (a neighbour list or a fixture list used when
%% a contact may be missing from it) is applied to the source text at test
%% time, compiled under a module name of its own into this case's private
%% directory (no mutant is ever committed or left on the code path), and
%% must make prop_island_equals_all_pairs fail within ?MUTANT_TESTS cases.
%% The unmutated source, compiled the same way, must pass: the mutation,
%% not the copy, is what fails. Each mutated text must occur exactly once
%% in rw_island.erl: when the source changes, this case fails until the
%% mutations are brought up to date (they can never silently test nothing).
%% (Changing the drift term is not among them: whatever one vector is taken
%% off every member's move, two members that each moved less than half the
%% skin relative to it moved less than the skin relative to each other; the
%% first member's move only keeps the list of a pile falling as one. A
%% drift reversed or dropped, tried, is rightly not caught.)
island_mutants_are_caught(Config) ->
    Dir = ?config(priv_dir, Config),
    Source = filename:join([code:lib_dir(rw_physics), "src", "rw_island.erl"]),
    {ok, Bin} = file:read_file(Source),
    Text = binary_to_list(Bin),
    Control = compile_copy(Dir, Text, rw_island_copy),
    true = proper:quickcheck(rw_physics_prop:prop_island_equals_all_pairs(Control),
                             [{numtests, 200}, {to_file, user}, long_result]),
    proper:global_state_erase(),
    Caught = [begin
                  1 = count(Text, From),
                  Mutant = compile_copy(Dir, string:replace(Text, From, To), list_to_atom("rw_island_" ++ atom_to_list(Name))),
                  case catch_mutant(Mutant, ?MUTANT_ROUNDS) of
                      survived -> ct:fail({mutant_survived, Name, From, To});
                      {Round, Counterexample} ->
                          ct:pal("~p (~s -> ~s) caught in round ~b by ~P", [Name, From, To, Round, Counterexample, 12]),
                          Name
                  end
              end || {Name, From, To} <- island_mutations()],
    {comment, io_lib:format("~b mutants caught", [length(Caught)])}.

%% The first counterexample to the island property with Mutant, within
%% Rounds rounds of ?MUTANT_TESTS random cases each.
catch_mutant(_Mutant, 0) -> survived;
catch_mutant(Mutant, Rounds) ->
    case proper:quickcheck(rw_physics_prop:prop_island_equals_all_pairs(Mutant),
                           [{numtests, ?MUTANT_TESTS}, noshrink, {to_file, user}, long_result]) of
        true ->
            proper:global_state_erase(),
            catch_mutant(Mutant, Rounds - 1);
        [Counterexample] ->
            proper:global_state_erase(),
            {?MUTANT_ROUNDS - Rounds + 1, Counterexample}
    end.

%% {Name, Text, Replacement}: rules that, so broken, let a list miss a
%% contact that a test of every pair finds.
island_mutations() ->
    [%% a neighbour list valid while members move a whole skin, not half:
     %% two members closing from either side then cover twice the skin
     {full_skin, "Limit = 0.5 * Skin - 1.0e-9 * Scale", "Limit = Skin - 1.0e-9 * Scale"},
     %% with CCD, a member's displacement over the substep no longer counts
     %% against the list's margin
     {no_ccd_spread, "Moved + Times * vlen(vsub(element(K, Disps), Disp0)) =< Limit", "Moved =< Limit"},
     %% without CCD moves are compared squared: against the limit itself,
     %% not squared, members may move several times half the skin
     {unsquared_limit, "Anchors, Drift, Limit * Limit)", "Anchors, Drift, Limit)"},
     %% with CCD, a member's reach only its free move, not the twice that
     %% a leg after a bounce may take it (a fast spin thrown by a floor)
     {ccd_reach_once, "-define(CCD_REACH, 2.0).", "-define(CCD_REACH, 1.0)."},
     %% fixtures listed only when within a radius of a member, without the
     %% half skin it may still move
     {no_fixture_margin, "R + 0.5 * Reach)", "R)"},
     %% a floor listed only within half that reach
     {plane_half_reach, "vdot(N, P) - Off < Reach +", "vdot(N, P) - Off < 0.5 * Reach +"},
     %% a container's top wall never listed
     {container_without_top, "orelse\n        Z - (CZ - EZ) < Near orelse (CZ + EZ) - Z < Near;",
      "orelse\n        Z - (CZ - EZ) < Near;"}].

count(Text, Part) -> length(string:split(Text, Part, all)) - 1.

%% Text (rw_island's source) compiled and loaded as module Name.
compile_copy(Dir, Text, Name) ->
    Renamed = string:replace(Text, "-module(rw_island).", "-module(" ++ atom_to_list(Name) ++ ").", leading),
    File = filename:join(Dir, atom_to_list(Name) ++ ".erl"),
    ok = file:write_file(File, Renamed),
    {ok, Name, Beam} = compile:file(File, [binary, return_errors, {i, code:lib_dir(rw_physics, include)}]),
    {module, Name} = code:load_binary(Name, File, Beam),
    Name.
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
