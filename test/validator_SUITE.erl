%% The scene validator under random mutation: every mutation of a valid
%% scene is either accepted, and then runs on both engines, or rejected with
%% a one-line message naming a JSON path. It never crashes.
-module(validator_SUITE).
-include_lib("proper/include/proper.hrl").
-include_lib("common_test/include/ct.hrl").
-export([all/0, suite/0, mutated_scenes_accepted_or_rejected/1]).

suite() -> [{timetrap, {minutes, 10}}].

all() -> [mutated_scenes_accepted_or_rejected].

%% Small valid scenes to mutate: every scene kind (spheres only, fixtures,
%% generators) is represented.
bases() ->
    [begin
         {ok, Bin} = file:read_file(rw_test_lib:scenario(F)),
         jiffy:decode(Bin, [return_maps])
     end || F <- ["head_on_elastic.json", "ball_drop.json", "newtons_cradle.json", "fast_thin_wall.json",
                  "unequal_masses.json", "projectile.json"]].

mutated_scenes_accepted_or_rejected(_Config) ->
    Bases = bases(),
    Prop = ?FORALL({Base, Mutations}, {elements(Bases), non_empty(list(mutation()))},
                   begin
                       Scene = lists:foldl(fun apply_mutation/2, Base, Mutations),
                       {Outcome, Ok} = check(Scene),
                       collect(Outcome, ?WHENFAIL(io:format("mutations ~p~nscene ~s~n",
                                                            [Mutations, jiffy:encode(Scene)]), Ok))
                   end),
    true = proper:quickcheck(Prop, [{numtests, 300}, {to_file, user}, long_result]),
    %% both outcomes must occur, or the property tests nothing
    Counts = [check(lists:foldl(fun apply_mutation/2, B, M))
              || {B, M} <- [{hd(Bases), [{[<<"bodies">>, 0, <<"radius">>], {set, 0.25}}]},
                            {hd(Bases), [{[<<"bodies">>, 0, <<"radius">>], {set, -1}}]}]],
    [{accepted, true}, {rejected, true}] = Counts,
    ok.

%% PropEr 1.2 cannot report an exception inside a property: catch it here.
check(Scene) ->
    try rw_scene:from_binary(iolist_to_binary(jiffy:encode(Scene)), #{overrides => #{duration_ms => 20}}) of
        {ok, S} ->
            {ok, #{frames := _}} = rw_reference:run(S, #{}),
            {ok, #{frames := _}} = rw_timewarp:run(S, #{buckets => 4}),
            {accepted, true};
        {error, E} ->
            Msg = rw_scene:format_error(E),
            case io_lib:printable_unicode_list(Msg) andalso not lists:member($\n, Msg)
                andalso lists:prefix("$", Msg) of
                true -> {rejected, true};
                false -> io:format("bad rejection message: ~p~n", [Msg]), {rejected, false}
            end
    catch
        Class:Reason:Stack ->
            io:format("validator or run crashed: ~p:~p~n~p~n", [Class, Reason, Stack]),
            {crashed, false}
    end.

%%% Mutations: a path into the scene (keys and list positions, chosen
%%% modulo what is there) and what to do at its end.

mutation() ->
    {list(oneof([key(), range(0, 5)])), oneof([{set, json_value()}, delete, {add_key, key()}])}.

key() ->
    elements([<<"name">>, <<"duration_ms">>, <<"substep_ms">>, <<"stride_ms">>, <<"frame_ms">>, <<"model">>,
              <<"bodies">>, <<"generators">>, <<"radius">>, <<"mass">>, <<"position">>, <<"velocity">>,
              <<"shape">>, <<"id">>, <<"static">>, <<"normal">>, <<"offset">>, <<"half_extents">>, <<"axis">>,
              <<"gravity">>, <<"restitution">>, <<"friction">>, <<"integrator">>, <<"ccd">>, <<"rotation">>,
              <<"count">>, <<"spacing">>, <<"bogus">>]).

json_value() ->
    ?SIZED(Size, json_value(min(Size, 3))).

json_value(0) ->
    oneof([integer(), float(), elements([0, -1, 1, 0.0, -0.0, 1.0e300, -1.0e300, 1.0e-300, 5.0e-324,
                                         1 bsl 70, 999999999999]),
           elements([true, false, null, <<>>, <<"sphere">>, <<"plane">>, <<"box">>, <<"cylinder">>,
                     <<"verlet">>, <<"x">>, <<"é"/utf8>>]),
           ?LET(S, list(range(32, 126)), list_to_binary(S))]);
json_value(N) ->
    oneof([json_value(0),
           ?LET(L, list(json_value(N - 1)), L),
           ?LET(L, vector(3, oneof([float(), integer()])), L),
           ?LET(KVs, list({key(), json_value(N - 1)}), maps:from_list(KVs))]).

apply_mutation({Path, Op}, Json) -> at(Path, Op, Json).

at([], {set, V}, _) -> V;
at([], _, Json) -> Json;
at([K], delete, Map) when is_map(Map), is_binary(K) -> maps:remove(K, Map);
at([K], {add_key, New}, Map) when is_map(Map), is_binary(K) -> Map#{New => maps:get(K, Map, 1)};
at([K | Rest], Op, Map) when is_map(Map), is_binary(K) ->
    case Map of
        #{K := V} -> Map#{K := at(Rest, Op, V)};
        _ when Rest =:= [], element(1, Op) =:= set -> Map#{K => element(2, Op)};
        _ -> Map
    end;
at([I | Rest], Op, List) when is_list(List), is_integer(I), List =/= [] ->
    N = I rem length(List) + 1,
    {Before, [X | After]} = lists:split(N - 1, List),
    case {Rest, Op} of
        {[], delete} -> Before ++ After;
        _ -> Before ++ [at(Rest, Op, X) | After]
    end;
at(_, _, Json) -> Json.
