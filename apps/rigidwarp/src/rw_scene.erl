%% @doc Scene files: JSON in, a validated `#scene{}' out. Every error names
%% the file, the JSON path of the offending field and what is wrong with
%% it. Nothing is started before a scene validates.
%%
%% A scene is one JSON object:
%% <ul>
%% <li>`name' (required), `description';</li>
%% <li>`duration_ms' (required), `substep_ms' (default 1), `stride_ms'
%%     (LVT_ub - GVT, default 64 substeps), `frame_ms' (the time between
%%     frames, default 10 substeps): ms in whole microseconds (0.5 is a
%%     substep), each a multiple of the substep;</li>
%% <li>`model': `gravity' [x, y, z] (left out: none), `restitution' in
%%     [0, 1] (default 1), `friction' (left out: frictionless), `rotation'
%%     (default false), `integrator' (`"symplectic_euler"' by default,
%%     `"verlet"' or `"explicit_euler"'), `ccd' (swept tests, default
%%     false), `rest_speed', `correction' (default 0.2) and `slop'
%%     (default 0);</li>
%% <li>`bodies', each with a unique `id' and a `shape' (`static' is
%%     optional: spheres move, the other shapes do not): a dynamic
%%     `"sphere"' (`radius', `mass', `position', `velocity',
%%     `angular_velocity' with rotation) or a static `"cylinder"'
%%     (`radius', `half_length', `axis', `position'), `"plane"' (`normal',
%%     `offset': the solid side is where normal.x is less than offset) or
%%     `"box"' (`half_extents', `position', `hollow': a container);</li>
%% <li>`generators' of spheres: `"grid"' (`count' [nx, ny, nz], `origin',
%%     `spacing') and `"random"' (`count', `seed', the region `min' and
%%     `max', `speed'), each with `id_prefix', `radius', `mass' and
%%     `velocity';</li>
%% <li>`cell_size' (the hash cell edge, default 5 times the largest radius)
%%     and `buckets' (bucket processes, default 64).</li>
%% </ul>
%% Unknown keys, keys given twice in an object, wrong types, numbers above
%% 1e12 in magnitude, duplicate ids and bodies that overlap at the start
%% are refused, and so is what the engines cannot hold
%% (`rw_scene_limits'): radii below 1e-9 m and masses below 1e-20
%% kg, a `cell_size' below an eighth of the largest radius, cell indices
%% beyond 2^53, and with CCD speeds whose sweeps would list too many
%% cells.
%%
%% ```
%% {"name": "two_balls", "duration_ms": 2000, "substep_ms": 1, "frame_ms": 10,
%%  "model": {"gravity": [0, -9.81, 0], "restitution": 0.8},
%%  "bodies": [
%%   {"id": "a", "shape": "sphere", "radius": 0.5, "mass": 1.0,
%%    "position": [0, 1, 0], "velocity": [2, 0, 0]},
%%   {"id": "floor", "shape": "plane", "static": true, "normal": [0, 1, 0], "offset": 0.0}]}
%% '''
-module(rw_scene).
-include("rigidwarp.hrl").
-include_lib("kernel/include/file.hrl").
-export([load/1, load/2, from_map/2, from_binary/2, format_error/1, max_abs/0, ms/2, us_to_ms/1, whole_ms/1, duration_ms/1,
         fingerprint/1, from_checkpoint/2]).
-export_type([error/0, overrides/0]).

-type path() :: [binary() | non_neg_integer()].
%% Where in the JSON: keys and 0-based array positions.
-type error() :: {scene_error, File :: string() | undefined, path(), Message :: string()}.
%% What is wrong and where; format_error/1 makes it one line.
-type overrides() :: #{duration_ms => number(), substep_ms => number(),
                       stride_ms => number(), frame_ms => number(),
                       buckets => pos_integer(), integrator => rw_integrate:integrator(),
                       ccd => boolean()}.
%% Values that replace the scene's own (from CLI flags or the shell).
%% Times in ms (whole microseconds: 0.5 is a valid substep).

%% Coordinates, speeds and sizes beyond this are rejected: far enough for
%% scenes around +-1e9 m, near enough that squared distances stay finite.
-define(MAX_ABS, 1.0e12).
-define(MAX_FILE_BYTES, 64 * 1024 * 1024).
%% The smallest squared length of a direction (from the shortest one,
%% 1e-150, whose square is still far above the denormal doubles).
-define(MIN_LEN2, 1.0e-300).

%% @doc The largest magnitude a coordinate, speed or size may have.
-spec max_abs() -> float().
max_abs() -> ?MAX_ABS.

%% @doc Read and validate a scene file.
-spec load(file:filename()) -> {ok, #scene{}} | {error, error()}.
load(File) -> load(File, #{}).

%% @doc Read and validate a scene file, with Overrides in place of its own
%% values.
-spec load(file:filename(), overrides()) -> {ok, #scene{}} | {error, error()}.
load(File0, Overrides) ->
    File = unicode:characters_to_list(File0),
    case file:read_file_info(File) of
        {ok, #file_info{size = Size}} when Size > ?MAX_FILE_BYTES ->
            {error, {scene_error, File, [], "file is larger than 64 MiB; not a scene"}};
        _ ->
            case file:read_file(File) of
                {ok, Bin} -> from_binary(Bin, #{file => File, overrides => Overrides});
                {error, Reason} ->
                    {error, {scene_error, File, [], "cannot read file: " ++ file:format_error(Reason)}}
            end
    end.

%% @doc Validate a scene from its JSON text; file names it in errors.
-spec from_binary(binary(), #{file => string(), overrides => overrides()}) ->
          {ok, #scene{}} | {error, error()}.
from_binary(Bin, Opts) ->
    File = maps:get(file, Opts, undefined),
    case decode(Bin) of
        {ok, Map} -> from_map(Map, Opts);
        {error, Path, Msg} -> {error, {scene_error, File, Path, Msg}}
    end.

%% @doc Validate a scene from its decoded JSON (maps with binary keys).
-spec from_map(term(), #{file => string(), overrides => overrides()}) ->
          {ok, #scene{}} | {error, error()}.
from_map(Map, Opts) ->
    File = maps:get(file, Opts, undefined),
    try
        {ok, build(Map, maps:get(overrides, Opts, #{}), File)}
    catch
        throw:{invalid, Path, Msg} -> {error, {scene_error, File, Path, Msg}}
    end.

%% @doc One line: the file, the JSON path and the problem, as in
%% `scenes/x.json: $.bodies[3].radius: must be positive, got -1.0'.
-spec format_error(error()) -> string().
format_error({scene_error, File, Path, Msg}) ->
    Where = case File of undefined -> ""; _ -> File ++ ": " end,
    lists:flatten([Where, format_path(Path), ": ", Msg]).

%%% Decoding

decode(Bin) ->
    case blank(Bin) of
        true -> {error, [], "the file is empty (a scene is a JSON object)"};
        false -> decode_json(Bin)
    end.

blank(<<C, Rest/binary>>) when C =:= $\s; C =:= $\t; C =:= $\r; C =:= $\n -> blank(Rest);
blank(Bin) -> Bin =:= <<>>.

%% Objects are decoded as lists of pairs, which keep a key given twice
%% (maps would keep one of them silently), and made maps once no object
%% has one.
decode_json(Bin) ->
    try jiffy:decode(Bin, []) of
        {Pairs} = Object when is_list(Pairs) ->
            try {ok, to_maps(Object, [])}
            catch throw:{duplicate_key, Path} -> {error, Path, "duplicate key (a key may appear once in an object)"}
            end;
        _ -> {error, [], "a scene must be a JSON object"}
    catch
        error:{Pos, truncated_json} when is_integer(Pos) ->
            {error, [], "invalid JSON: the text ends early"};
        error:{Pos, _Reason} when is_integer(Pos) ->
            {error, [], json_error_at(Bin, Pos)};
        error:{range, _} ->
            {error, [], "invalid JSON: a number is too large for a double"};
        error:_ ->
            {error, [], "invalid JSON"}
    end.

%% Decoded JSON with objects as maps; a key given twice in an object
%% throws {duplicate_key, Path}, its second place.
to_maps({Pairs}, Path) when is_list(Pairs) ->
    lists:foldl(fun({K, V}, Map) ->
                        case is_map_key(K, Map) of
                            true -> throw({duplicate_key, Path ++ [K]});
                            false -> Map#{K => to_maps(V, Path ++ [K])}
                        end
                end, #{}, Pairs);
to_maps(List, Path) when is_list(List) ->
    {Items, _} = lists:mapfoldl(fun(V, I) -> {to_maps(V, Path ++ [I]), I + 1} end, 0, List),
    Items;
to_maps(Value, _Path) -> Value.

%% Where jiffy stopped, as a person counts: line, column and the character.
json_error_at(Bin, Pos) ->
    Offset = max(0, min(Pos - 1, byte_size(Bin))),
    Before = binary:part(Bin, 0, Offset),
    Lines = binary:split(Before, <<"\n">>, [global]),
    Col = byte_size(lists:last(Lines)) + 1,
    What = case Offset < byte_size(Bin) of
               true ->
                   case binary:at(Bin, Offset) of
                       C when C >= 32, C < 127 -> io_lib:format("unexpected '~c'", [C]);
                       C -> io_lib:format("unexpected byte 0x~2.16.0B", [C])
                   end;
               false -> "unexpected end"
           end,
    Hint = case binary:part(Bin, Offset, min(8, byte_size(Bin) - Offset)) of
               <<"NaN", _/binary>> -> " (NaN is not a JSON number)";
               <<"Infinity", _/binary>> -> " (Infinity is not a JSON number)";
               <<"-Infinity", _/binary>> -> " (Infinity is not a JSON number)";
               <<"'", _/binary>> -> " (JSON strings use double quotes)";
               _ -> ""
           end,
    lists:flatten(io_lib:format("invalid JSON at line ~b, column ~b: ~s~s", [length(Lines), Col, What, Hint])).

%%% Building

-define(TOP_KEYS, [<<"name">>, <<"description">>, <<"duration_ms">>, <<"substep_ms">>,
                   <<"stride_ms">>, <<"frame_ms">>, <<"model">>, <<"bodies">>,
                   <<"generators">>, <<"cell_size">>, <<"buckets">>]).

build(Map, Overrides, File) ->
    object(Map, []),
    known_keys(Map, ?TOP_KEYS, []),
    Name = string_field(Map, <<"name">>, [], required),
    _ = string_field(Map, <<"description">>, [], <<>>),
    %% times are read in whole microseconds, then counted in ticks
    Substep = time_field(substep_ms, Map, Overrides, 1000),
    Duration = time_field(duration_ms, Map, Overrides, required),
    Stride = time_field(stride_ms, Map, Overrides, 64 * Substep),
    Frame = time_field(frame_ms, Map, Overrides, 10 * Substep),
    multiple_of(Duration, Substep, [<<"duration_ms">>]),
    multiple_of(Stride, Substep, [<<"stride_ms">>]),
    multiple_of(Frame, Substep, [<<"frame_ms">>]),
    %% every time is a multiple of the substep, so this tick divides them all
    Tick = gcd(1000, Substep),
    Model = model_overrides(model(maps:get(<<"model">>, Map, #{}), Substep / 1.0e6), Overrides),
    Bodies = list_field(Map, <<"bodies">>, []),
    Gens = list_field(Map, <<"generators">>, []),
    at_most_max_bodies(length(Bodies), Gens),
    Generated = generators(Gens),
    Parsed = [body(B, [<<"bodies">>, I]) || {I, B} <- enumerate(Bodies)] ++ Generated,
    unique_ids(Parsed),
    Ranked = rank(Parsed),
    Spheres0 = [{S, St, P} || {sphere, S, St, P} <- Ranked],
    Fixtures = [F || {fixture, F, _P} <- Ranked],
    Spheres0 =:= [] andalso throw({invalid, [<<"bodies">>], "the scene has no dynamic body (sphere)"}),
    Spheres = with_rotation(Spheres0, Model),
    MaxR = lists:max([R || {#sphere{radius = R}, _, _} <- Spheres]),
    CellSize = case maps:find(<<"cell_size">>, Map) of
                   {ok, _} -> positive(Map, <<"cell_size">>, []);
                   %% 5 radii: a sphere's box mostly stays in one cell
                   %% for a whole step (one run per write, less hashing and
                   %% bucket work) while a cell still holds few bodies;
                   %% smaller cells put a step over more cells, larger
                   %% ones put more bodies in each
                   error -> 5.0 * MaxR
               end,
    %% before anything lists the cells of a sphere
    case rw_scene_limits:check(Spheres, CellSize, Model, {Duration / 1.0e6, min(Stride, Duration) div Substep}) of
        ok -> ok;
        {error, Path, Msg} -> throw({invalid, Path, Msg})
    end,
    no_overlaps(Spheres, Fixtures, CellSize),
    Buckets = override(buckets, Overrides,
                       fun() -> case maps:is_key(<<"buckets">>, Map) of
                                    true -> pos_int(Map, <<"buckets">>, [], required);
                                    false -> undefined
                                end end),
    #scene{name = Name, file = File, tick_us = Tick, duration = Duration div Tick, substep = Substep div Tick,
           stride = Stride div Tick, frame = Frame div Tick, model = Model,
           spheres = [S || {S, _, _} <- Spheres], initial = [St || {_, St, _} <- Spheres],
           fixtures = Fixtures, cell_size = CellSize, buckets = Buckets}.

override(Key, Overrides, Default) ->
    case maps:find(Key, Overrides) of
        {ok, V} -> V;
        error -> Default()
    end.

multiple_of(X, Substep, Path) ->
    X rem Substep =:= 0 orelse
        throw({invalid, Path, fmt("~s ms is not a multiple of the substep (~s ms)",
                                  [format_ms(X), format_ms(Substep)])}).

gcd(A, 0) -> A;
gcd(A, B) -> gcd(B, A rem B).

%% A time in ms from the overrides or the scene, as whole microseconds.
time_field(Key, Map, Overrides, Default) ->
    Name = atom_to_binary(Key),
    case maps:find(Key, Overrides) of
        {ok, V} -> to_us(V, [Name]);
        error ->
            case get(Map, Name, [], Default) of
                {default, D} -> D;
                V -> to_us(V, [Name])
            end
    end.

%% Milliseconds to whole microseconds: 0.5 and 0.001 are fine, 0.0005 is
%% finer than the finest tick.
to_us(X, _Path) when is_integer(X), X > 0, X =< 1 bsl 40 -> X * 1000;
to_us(X, Path) when is_integer(X), X > 0 -> invalid(Path, "is too large (~b)", [X]);
to_us(X, Path) when is_float(X), X > 0.0, X =< 1.0e12 ->
    Us = round(X * 1000),
    case Us > 0 andalso abs(X * 1000 - Us) =< 1.0e-6 * Us of
        true -> Us;
        false -> invalid(Path, "must be a whole number of microseconds (0.001 ms at the finest), got ~p ms", [X])
    end;
to_us(X, Path) -> invalid(Path, "must be a positive number of milliseconds, got ~s", [describe(X)]).

format_ms(Us) -> io_lib:format("~w", [us_to_ms(Us)]).

%% @doc Whole microseconds to ms: an integer when whole (20, 0.5).
-spec us_to_ms(integer()) -> number().
us_to_ms(Us) when Us rem 1000 =:= 0 -> Us div 1000;
us_to_ms(Us) -> Us / 1000.

%% @doc Ticks of Scene to milliseconds (an integer when whole, as every
%% frame time of a scene with a 1 ms tick is). Negative (no frame yet)
%% stays.
-spec ms(#scene{}, integer()) -> number().
ms(#scene{tick_us = 1000}, T) -> T;
ms(_Scene, T) when T < 0 -> T;
ms(#scene{tick_us = U}, T) -> us_to_ms(T * U).

%% @doc What identifies a run's frames: everything the frames depend on
%% (bodies, fixtures, model, times), not where the scene was read from nor
%% its name nor the bucket count. A checkpoint is only resumed by a run
%% with the same fingerprint.
-spec fingerprint(#scene{}) -> binary().
fingerprint(#scene{} = Scene) ->
    erlang:md5(term_to_binary(Scene#scene{name = <<>>, file = undefined, buckets = undefined},
                              [{minor_version, 2}])).

%% @doc The scene as it stands at a checkpoint: the same run, from there
%% on.
-spec from_checkpoint(#scene{}, rw_reference:checkpoint()) -> #scene{}.
from_checkpoint(#scene{spheres = Spheres} = Scene, {checkpoint, Tick, _Ms, States})
  when length(States) =:= length(Spheres) ->
    Scene#scene{start = Tick, initial = States}.

%% @doc How long the scene runs, in ms.
-spec duration_ms(#scene{}) -> number().
duration_ms(#scene{duration = D} = Scene) -> ms(Scene, D).

%% @doc A time in ms as an integer when it is whole (frame times, keys of
%% the frame ring), so that 20 and 20.0 name the same frame.
-spec whole_ms(number()) -> number().
whole_ms(Ms) when is_float(Ms), Ms == trunc(Ms) -> trunc(Ms);
whole_ms(Ms) -> Ms.

-define(MODEL_KEYS, [<<"gravity">>, <<"restitution">>, <<"friction">>, <<"rotation">>,
                     <<"integrator">>, <<"ccd">>, <<"rest_speed">>, <<"correction">>, <<"slop">>]).

model(M, Dt) ->
    P = [<<"model">>],
    object(M, P),
    known_keys(M, ?MODEL_KEYS, P),
    Gravity = case maps:is_key(<<"gravity">>, M) of
                  true -> vec(M, <<"gravity">>, P);
                  false -> undefined
              end,
    Restitution = number(M, <<"restitution">>, P, 1.0),
    (Restitution >= 0.0 andalso Restitution =< 1.0) orelse
        invalid(P ++ [<<"restitution">>], "must be between 0 and 1, got ~p", [Restitution]),
    Friction = case maps:is_key(<<"friction">>, M) of
                   true -> non_negative(M, <<"friction">>, P);
                   false -> undefined
               end,
    Integrator = case maps:get(<<"integrator">>, M, <<"symplectic_euler">>) of
                     <<"symplectic_euler">> -> symplectic_euler;
                     <<"verlet">> -> verlet;
                     <<"explicit_euler">> -> explicit_euler;
                     Other -> invalid(P ++ [<<"integrator">>],
                                      "must be \"symplectic_euler\", \"verlet\" or \"explicit_euler\", got ~s",
                                      [jiffy:encode(Other)])
                 end,
    RestDefault = case Gravity of
                      undefined -> 0.0;
                      _ -> 2.0 * rw_vec:len(Gravity) * Dt
                  end,
    #model{dt = Dt, gravity = case Gravity of {0.0, 0.0, 0.0} -> undefined; _ -> Gravity end,
           restitution = Restitution, friction = Friction,
           rotation = boolean(M, <<"rotation">>, P, false),
           integrator = Integrator,
           ccd = boolean(M, <<"ccd">>, P, false),
           rest_speed = non_negative(M, <<"rest_speed">>, P, RestDefault),
           correction = fraction(M, <<"correction">>, P, 0.2),
           slop = non_negative(M, <<"slop">>, P, 0.0)}.

%% The integrator and CCD can be chosen per run (rw_accuracy sweeps them).
model_overrides(Model, Overrides) ->
    Model#model{integrator = maps:get(integrator, Overrides, Model#model.integrator),
                ccd = maps:get(ccd, Overrides, Model#model.ccd)}.

-define(SPHERE_KEYS, [<<"id">>, <<"shape">>, <<"static">>, <<"radius">>, <<"mass">>,
                      <<"position">>, <<"velocity">>, <<"angular_velocity">>]).
-define(CYLINDER_KEYS, [<<"id">>, <<"shape">>, <<"static">>, <<"radius">>, <<"half_length">>,
                        <<"axis">>, <<"position">>]).
-define(PLANE_KEYS, [<<"id">>, <<"shape">>, <<"static">>, <<"normal">>, <<"offset">>]).
-define(BOX_KEYS, [<<"id">>, <<"shape">>, <<"static">>, <<"half_extents">>, <<"position">>,
                   <<"hollow">>]).

%% A parsed body before ranking: {sphere, Id, Radius, Mass, State, Path}
%% or {fixture, Id, Shape, Path}.
body(B, P) ->
    object(B, P),
    Id = string_field(B, <<"id">>, P, required),
    Shape = string_field(B, <<"shape">>, P, required),
    Static = boolean(B, <<"static">>, P, Shape =/= <<"sphere">>),
    case Shape of
        <<"sphere">> ->
            known_keys(B, ?SPHERE_KEYS, P),
            Static andalso invalid(P ++ [<<"static">>], "static spheres are not supported; use a dynamic sphere", []),
            St = #st{p = vec(B, <<"position">>, P),
                     v = vec(B, <<"velocity">>, P, rw_vec:zero()),
                     w = vec(B, <<"angular_velocity">>, P, undefined)},
            {sphere, Id, radius(B, P), mass(B, P), St, P};
        _ when Shape =:= <<"cylinder">>; Shape =:= <<"plane">>; Shape =:= <<"box">> ->
            Static orelse invalid(P ++ [<<"static">>], "a ~s must be static (only spheres move)", [Shape]),
            {fixture, Id, static_shape(Shape, B, P), P};
        _ ->
            invalid(P ++ [<<"shape">>], "unknown shape ~s (expected sphere, cylinder, plane or box)",
                    [jiffy:encode(Shape)])
    end.

static_shape(<<"cylinder">>, B, P) ->
    known_keys(B, ?CYLINDER_KEYS, P),
    {cylinder, vec(B, <<"position">>, P), unit_vec(B, <<"axis">>, P, {0.0, 1.0, 0.0}),
     positive(B, <<"radius">>, P), positive(B, <<"half_length">>, P)};
static_shape(<<"plane">>, B, P) ->
    known_keys(B, ?PLANE_KEYS, P),
    {plane, unit_vec(B, <<"normal">>, P, required), number(B, <<"offset">>, P, 0.0)};
static_shape(<<"box">>, B, P) ->
    known_keys(B, ?BOX_KEYS, P),
    E = vec(B, <<"half_extents">>, P),
    [invalid(P ++ [<<"half_extents">>], "every half extent must be positive, got ~p", [X])
     || X <- tuple_to_list(E), X =< 0.0],
    Kind = case boolean(B, <<"hollow">>, P, false) of true -> hollow; false -> solid end,
    {box, vec(B, <<"position">>, P), E, Kind}.

unique_ids(Parsed) ->
    _ = lists:foldl(fun(Body, Seen) ->
                        {Id, P} = id_and_path(Body),
                        case maps:find(Id, Seen) of
                            {ok, First} ->
                                invalid(P ++ [<<"id">>], "duplicate id ~s (first used at ~s)",
                                        [jiffy:encode(Id), format_path(First)]);
                            error -> Seen#{Id => P}
                        end
                end, #{}, Parsed),
    ok.

id_and_path({sphere, Id, _, _, _, P}) -> {Id, P};
id_and_path({fixture, Id, _, P}) -> {Id, P}.

rank(Parsed) ->
    Sorted = lists:sort(fun(A, B) -> element(1, id_and_path(A)) =< element(1, id_and_path(B)) end, Parsed),
    [ranked(Idx, Body) || {Idx, Body} <- enumerate(Sorted)].

ranked(Idx, {sphere, Id, R, M, St, P}) -> {sphere, rw_shape:sphere(Idx, Id, R, M), St, P};
ranked(Idx, {fixture, Id, Shape, P}) -> {fixture, rw_shape:fixture(Idx, Id, Shape), P}.

%% Angular state exists only where rotation is modelled.
with_rotation(Spheres, #model{rotation = true}) ->
    [{S, St#st{q = rw_quat:identity(), w = case W of undefined -> rw_vec:zero(); _ -> W end}, P}
     || {S, #st{w = W} = St, P} <- Spheres];
with_rotation(Spheres, #model{rotation = false}) ->
    [invalid(P ++ [<<"angular_velocity">>], "needs \"rotation\": true in the model", [])
     || {_, #st{w = W}, P} <- Spheres, W =/= undefined],
    Spheres.

%% No two spheres may overlap at the start, nor a sphere and a fixture.
no_overlaps(Spheres, Fixtures, CellSize) ->
    ByPos = list_to_tuple(Spheres),
    BoxOf = fun(K) -> {#sphere{radius = R}, #st{p = Pos}, _} = element(K, ByPos), rw_shape:sphere_aabb(Pos, R) end,
    [overlap(element(A, ByPos), element(B, ByPos))
     || {A, B} <- rw_broadphase:grid(tuple_size(ByPos), BoxOf, CellSize)],
    [fixture_overlap(S, F) || S <- Spheres, F <- Fixtures],
    ok.

%% Reported at whichever of the two comes later in the file.
overlap({#sphere{radius = RA, id = IdA}, #st{p = PA}, PathA}, {#sphere{radius = RB, id = IdB}, #st{p = PB}, PathB}) ->
    case rw_narrow:sphere_sphere(PA, RA, PB, RB) of
        none -> ok;
        #contact{depth = D} ->
            {Path, Id, Other} = case PathA > PathB of
                                    true -> {PathA, IdA, IdB};
                                    false -> {PathB, IdB, IdA}
                                end,
            invalid(Path ++ [<<"position">>], "sphere ~s overlaps sphere ~s by ~g m at the start",
                    [Id, Other, D])
    end.

fixture_overlap({#sphere{radius = R, id = Id}, #st{p = Pos}, Path}, #fixture{id = FId, shape = Shape}) ->
    case rw_narrow:sphere_fixture(Pos, R, Shape) of
        [] -> ok;
        [{_, #contact{depth = D}} | _] ->
            invalid(Path ++ [<<"position">>], "sphere ~s overlaps static ~s by ~g m at the start",
                    [Id, FId, D])
    end.

%%% Generators: grids and seeded random sets of spheres

-define(GRID_KEYS, [<<"type">>, <<"id_prefix">>, <<"count">>, <<"origin">>, <<"spacing">>,
                    <<"radius">>, <<"mass">>, <<"velocity">>]).
-define(RANDOM_KEYS, [<<"type">>, <<"id_prefix">>, <<"count">>, <<"seed">>, <<"min">>, <<"max">>,
                      <<"radius">>, <<"mass">>, <<"speed">>, <<"velocity">>]).
-define(MAX_GENERATED, 1000000).
%% A run's memory grows with its bodies (Time Warp: some 60 KiB a body at
%% the scenes' strides, measured on the gases of 20,000 and 50,000
%% spheres, 1.8 and 3.1 GB at their peak): past this many a scene is
%% refused before a sphere is generated, since placing a million random
%% spheres alone took 3.5 GB and two minutes.
-define(MAX_BODIES, 50000).

%% The bodies the scene asks for, counted before any is generated.
at_most_max_bodies(Listed, Gens) ->
    Asked = Listed + lists:sum([asked_count(G) || G <- Gens]),
    Asked =< ?MAX_BODIES orelse
        invalid([<<"generators">>], "the scene asks for ~b bodies, more than the ~b a run may hold",
                [Asked, ?MAX_BODIES]).

%% A generator's count where it is well formed (generator/2 names what is
%% wrong with any other).
asked_count(#{<<"count">> := N}) when is_integer(N), N > 0 -> N;
asked_count(#{<<"count">> := [NX, NY, NZ]}) when is_integer(NX), is_integer(NY), is_integer(NZ),
                                                  NX > 0, NY > 0, NZ > 0 -> NX * NY * NZ;
asked_count(_) -> 0.

generators(Gens) ->
    lists:append([generator(G, [<<"generators">>, I]) || {I, G} <- enumerate(Gens)]).

generator(G, P) ->
    object(G, P),
    case string_field(G, <<"type">>, P, required) of
        <<"grid">> -> grid(G, P);
        <<"random">> -> random_spheres(G, P);
        T -> invalid(P ++ [<<"type">>], "unknown generator type ~s (expected grid or random)",
                     [jiffy:encode(T)])
    end.

grid(G, P) ->
    known_keys(G, ?GRID_KEYS, P),
    Prefix = string_field(G, <<"id_prefix">>, P, required),
    [NX, NY, NZ] = int_list(G, <<"count">>, P, 3),
    N = NX * NY * NZ,
    Origin = vec(G, <<"origin">>, P, rw_vec:zero()),
    {SX, SY, SZ} = vec(G, <<"spacing">>, P),
    R = radius(G, P),
    M = mass(G, P),
    V = vec(G, <<"velocity">>, P, rw_vec:zero()),
    Width = length(integer_to_list(max(N - 1, 0))),
    Points = [rw_vec:add(Origin, {I * SX, J * SY, K * SZ})
              || I <- lists:seq(0, NX - 1), J <- lists:seq(0, NY - 1), K <- lists:seq(0, NZ - 1)],
    [{sphere, gen_id(Prefix, Seq, Width), R, M, #st{p = Pos, v = V}, P}
     || {Seq, Pos} <- enumerate(Points)].

random_spheres(G, P) ->
    known_keys(G, ?RANDOM_KEYS, P),
    Prefix = string_field(G, <<"id_prefix">>, P, required),
    N = pos_int(G, <<"count">>, P, required),
    Seed = non_neg_int(G, <<"seed">>, P, 1),
    Lo = vec(G, <<"min">>, P),
    Hi = vec(G, <<"max">>, P),
    R = radius(G, P),
    M = mass(G, P),
    Speed = non_negative(G, <<"speed">>, P, 0.0),
    V0 = vec(G, <<"velocity">>, P, rw_vec:zero()),
    [invalid(P ++ [<<"max">>], "the region must be wider than a sphere (2 * radius) on every axis", [])
     || {A, B} <- lists:zip(tuple_to_list(Lo), tuple_to_list(Hi)), B - A < 2.0 * R],
    Width = length(integer_to_list(N - 1)),
    Rand = rand:seed_s(exsss, Seed),
    Placed = place(N, N, R, Lo, Hi, Rand, #{}, [], 0, P),
    [{sphere, gen_id(Prefix, Seq, Width), R, M,
      #st{p = Pos, v = rw_vec:add(V0, rw_vec:scale(Dir, Mag * Speed))}, P}
     || {Seq, {Pos, Dir, Mag}} <- enumerate(Placed)].

%% Rejection sampling: positions uniform in the region shrunk by R, kept
%% when they touch no sphere placed before; N of Total left to place.
place(0, _Total, _R, _Lo, _Hi, _Rand, _Grid, Acc, _Tries, _P) ->
    lists:reverse(Acc);
place(N, Total, R, Lo, Hi, Rand0, Grid, Acc, Tries, P) ->
    Tries < 1000 * Total orelse
        invalid(P ++ [<<"count">>], "cannot place ~b spheres of radius ~g without overlap in the region",
                [Total, R]),
    {Pos, Rand1} = uniform_vec(rw_vec:add(Lo, {R, R, R}), rw_vec:sub(Hi, {R, R, R}), Rand0),
    {Dir, Mag, Rand2} = random_direction(Rand1),
    Cell = rw_hash:cell_of(Pos, 2.0 * R),
    {CX, CY, CZ} = Cell,
    Near = lists:append([maps:get({CX + I, CY + J, CZ + K}, Grid, [])
                         || I <- [-1, 0, 1], J <- [-1, 0, 1], K <- [-1, 0, 1]]),
    case lists:any(fun(Q) -> rw_vec:len2(rw_vec:sub(Q, Pos)) < 4.0 * R * R end, Near) of
        true -> place(N, Total, R, Lo, Hi, Rand2, Grid, Acc, Tries + 1, P);
        false -> place(N - 1, Total, R, Lo, Hi, Rand2, maps:update_with(Cell, fun(L) -> [Pos | L] end, [Pos], Grid),
                       [{Pos, Dir, Mag} | Acc], Tries + 1, P)
    end.

uniform_vec({LX, LY, LZ}, {HX, HY, HZ}, R0) ->
    {A, R1} = rand:uniform_s(R0),
    {B, R2} = rand:uniform_s(R1),
    {C, R3} = rand:uniform_s(R2),
    {{LX + A * (HX - LX), LY + B * (HY - LY), LZ + C * (HZ - LZ)}, R3}.

%% A uniformly distributed unit vector and a magnitude in [0, 1).
random_direction(R0) ->
    {U, R1} = rand:uniform_s(R0),
    {Phi, R2} = rand:uniform_s(R1),
    {Mag, R3} = rand:uniform_s(R2),
    Z = 2.0 * U - 1.0,
    S = math:sqrt(max(0.0, 1.0 - Z * Z)),
    A = 2.0 * math:pi() * Phi,
    {{S * math:cos(A), S * math:sin(A), Z}, Mag, R3}.

gen_id(Prefix, Seq, Width) ->
    iolist_to_binary([Prefix, string:pad(integer_to_list(Seq), Width, leading, $0)]).

%%% Field readers: each throws {invalid, Path, Message}

object(M, _P) when is_map(M) -> ok;
object(X, P) -> invalid(P, "must be an object, got ~s", [describe(X)]).

known_keys(M, Known, P) ->
    case [K || K <- maps:keys(M), not lists:member(K, Known)] of
        [] -> ok;
        [K | _] -> invalid(P ++ [K], "unknown key (known keys: ~s)",
                           [lists:join(", ", [binary_to_list(X) || X <- Known])])
    end.

get(M, K, P, Default) ->
    case maps:find(K, M) of
        {ok, V} -> V;
        error when Default =:= required -> invalid(P ++ [K], "is required", []);
        error -> {default, Default}
    end.

string_field(M, K, P, Default) ->
    case get(M, K, P, Default) of
        {default, D} -> D;
        <<>> -> invalid(P ++ [K], "must not be empty", []);
        B when is_binary(B) -> B;
        X -> invalid(P ++ [K], "must be a string, got ~s", [describe(X)])
    end.

list_field(M, K, P) ->
    case get(M, K, P, []) of
        {default, D} -> D;
        L when is_list(L) -> L;
        X -> invalid(P ++ [K], "must be an array, got ~s", [describe(X)])
    end.

boolean(M, K, P, Default) ->
    case get(M, K, P, Default) of
        {default, D} -> D;
        B when is_boolean(B) -> B;
        X -> invalid(P ++ [K], "must be true or false, got ~s", [describe(X)])
    end.

pos_int(M, K, P, Default) ->
    case get(M, K, P, Default) of
        {default, D} -> D;
        I when is_integer(I), I > 0, I =< 1 bsl 40 -> I;
        I when is_integer(I), I > 0 -> invalid(P ++ [K], "is too large (~b)", [I]);
        X -> invalid(P ++ [K], "must be a positive integer, got ~s", [describe(X)])
    end.

non_neg_int(M, K, P, Default) ->
    case get(M, K, P, Default) of
        {default, D} -> D;
        I when is_integer(I), I >= 0, I < 1 bsl 64 -> I;
        X -> invalid(P ++ [K], "must be a non-negative integer, got ~s", [describe(X)])
    end.

int_list(M, K, P, Len) ->
    case get(M, K, P, required) of
        L when is_list(L), length(L) =:= Len ->
            [case X of
                 I when is_integer(I), I > 0, I =< ?MAX_GENERATED -> I;
                 _ -> invalid(P ++ [K, J], "must be a positive integer up to ~b, got ~s",
                              [?MAX_GENERATED, describe(X)])
             end || {J, X} <- enumerate(L)];
        X -> invalid(P ++ [K], "must be an array of ~b positive integers, got ~s", [Len, describe(X)])
    end.

number(M, K, P, Default) ->
    case get(M, K, P, Default) of
        {default, D} -> D;
        X -> to_float(X, P ++ [K])
    end.

to_float(X, Path) when is_integer(X); is_float(X) ->
    case abs(X) =< ?MAX_ABS of
        true -> float(X);
        false -> invalid(Path, "must be at most ~g in magnitude, got ~s", [?MAX_ABS, describe(X)])
    end;
to_float(X, Path) ->
    invalid(Path, "must be a number, got ~s", [describe(X)]).

positive(M, K, P) ->
    case number(M, K, P, required) of
        X when X > 0.0 -> X;
        X -> invalid(P ++ [K], "must be positive, got ~p", [X])
    end.

%% A sphere's radius and mass: positive, and within rw_scene_limits' ranges.
radius(M, P) -> ranged(M, <<"radius">>, P, fun rw_scene_limits:radius/1).

mass(M, P) -> ranged(M, <<"mass">>, P, fun rw_scene_limits:mass/1).

ranged(M, K, P, Check) ->
    X = positive(M, K, P),
    case Check(X) of
        ok -> X;
        {error, Msg} -> throw({invalid, P ++ [K], Msg})
    end.

non_negative(M, K, P) -> non_negative(M, K, P, required).
non_negative(M, K, P, Default) ->
    case number(M, K, P, Default) of
        X when X >= 0.0 -> X;
        X -> invalid(P ++ [K], "must not be negative, got ~p", [X])
    end.

fraction(M, K, P, Default) ->
    case number(M, K, P, Default) of
        X when X >= 0.0, X =< 1.0 -> X;
        X -> invalid(P ++ [K], "must be between 0 and 1, got ~p", [X])
    end.

vec(M, K, P) -> vec(M, K, P, required).
vec(M, K, P, Default) ->
    case get(M, K, P, Default) of
        {default, D} -> D;
        [X, Y, Z] -> {to_float(X, P ++ [K, 0]), to_float(Y, P ++ [K, 1]), to_float(Z, P ++ [K, 2])};
        X -> invalid(P ++ [K], "must be an array of 3 numbers, got ~s", [describe(X)])
    end.

%% A direction, normalised. A vector whose squared length is far down
%% among the smallest doubles has no direction that normalising can find:
%% it is refused as degenerate, not taken as the short vector it stays.
unit_vec(M, K, P, Default) ->
    case vec(M, K, P, Default) of
        {0.0, 0.0, 0.0} -> invalid(P ++ [K], "must not be the zero vector", []);
        V ->
            case rw_vec:len2(V) >= ?MIN_LEN2 of
                true -> rw_vec:norm(V);
                false -> invalid(P ++ [K], "is degenerate: its length ~s is below 1.0e-150, too small to normalise, "
                                 "got ~s", [float_to_list(length_of(V), [short]), describe(tuple_to_list(V))])
            end
    end.

%% The length of a vector however short, without squaring it into zero.
length_of({X, Y, Z} = V) ->
    Largest = rw_vec:max_abs(V),
    Largest * rw_vec:len({X / Largest, Y / Largest, Z / Largest}).

-spec invalid(path(), string(), [term()]) -> no_return().
invalid(Path, Fmt, Args) -> throw({invalid, Path, fmt(Fmt, Args)}).

fmt(Fmt, Args) -> lists:flatten(io_lib:format(Fmt, Args)).

describe(X) ->
    Text = try iolist_to_binary(jiffy:encode(X)) catch _:_ -> <<"an unprintable value">> end,
    case byte_size(Text) > 40 of
        true -> [binary:part(Text, 0, 37), "..."];
        false -> Text
    end.

-spec format_path(path()) -> string().
format_path(Path) ->
    lists:flatten(["$" | [case S of
                              I when is_integer(I) -> ["[", integer_to_list(I), "]"];
                              B -> [".", binary_to_list(B)]
                          end || S <- Path]]).

enumerate(L) -> lists:zip(lists:seq(0, length(L) - 1), L).
