%% Speed versus accuracy: runs a scene over a sweep of substeps, strides,
%% integrators and CCD and measures, for each setting, the Time Warp
%% engine's realtime factor and the accuracy of its frames against the
%% exact event-driven solution (rw_exact). `rigidwarp bench accuracy`
%% (rw_cli_bench) prints, writes and plots what this returns.
%%
%% Per (scene, substep, integrator, CCD) one run of the reference engine
%% commits a frame at every substep (its frames are bit for bit those of
%% Time Warp, see engine_SUITE); the metrics come from those frames:
%%
%%   pos_err_max, pos_err_rms   |p - p_exact| over every frame and body (m)
%%   energy_drift       at restitution 1 (where energy is conserved): max over
%%                      frames |E(t) - E(0)| / (largest kinetic energy of the exact
%%                      solution), E = kinetic + potential (-m g.p); else undefined
%%   momentum_drift     without fixtures (where momentum is conserved, less
%%                      gravity's M g t): max over frames |P(t) - P(0) - M g t| /
%%                      (largest sum of m |v| of the exact solution); else undefined
%%   max_penetration    deepest sphere-sphere overlap or sphere-fixture
%%                      penetration in any frame (m)
%%   missed             substeps in which a centre went through a fixture's
%%                      surface (from its free side to its solid side) or two
%%                      centres passed each other (the line of centres turned
%%                      by more than 90 degrees while they came closer than the
%%                      sum of their radii): collisions the engine saw too
%%                      late to push the bodies back to their own sides, or not
%%                      at all (tunnelling)
%%   impacts            impacts in the exact solution
%%
%% Speed: for each stride, Time Warp runs the same setting with the scene's
%% own frame interval (rounded up to a multiple of the substep) and default
%% schedulers, at least min_runs times (default 3) and for at least
%% min_wall_ms (default 300) in all; the fastest run counts.
%% Stride changes only the speed: the frames, and so the accuracy, are the
%% same for every stride.
-module(rw_accuracy).
-include_lib("rigidwarp/include/rigidwarp.hrl").
-export([sweep/1, check_scene/1, measure/3, metrics/3, pareto/1, csv/1, table/1, columns/0, num/1,
         default_scenes/0, default_substeps/0, default_strides/0]).
-export_type([row/0, options/0, scene_spec/0]).

-type row() :: #{scene := binary(), substep_ms := number(), stride_ms := number(),
                 integrator := rw_integrate:integrator(), ccd := boolean(), sim_ms := number(),
                 wall_ms := float(), realtime_factor := float(), pos_err_max := float(),
                 pos_err_rms := float(), energy_drift := float() | undefined,
                 momentum_drift := float() | undefined, max_penetration := float(), missed := non_neg_integer(),
                 impacts := non_neg_integer(), pareto => boolean()}.
%% A scene file, or a scene file with its own end time (ms), which wins
%% over the `until` option.
-type scene_spec() :: file:filename() | {file:filename(), pos_integer()}.
%% Substeps and strides in ms: whole microseconds (0.5 is a substep).
-type options() :: #{scenes := [scene_spec()], substeps := [number()], strides := [number()],
                     integrators := [rw_integrate:integrator()], ccd := [boolean()],
                     until => pos_integer(), min_runs => pos_integer(), min_wall_ms => non_neg_integer(),
                     on_row => fun((map()) -> any())}.
-type accuracy() :: #{pos_err_max := float(), pos_err_rms := float(), energy_drift := float() | undefined,
                      momentum_drift := float() | undefined, max_penetration := float(),
                      missed := non_neg_integer(), impacts := non_neg_integer()}.

%% The sweep of `rigidwarp bench accuracy`, as NAME[:UNTIL_MS]: the scene's
%% own duration, except Bouncing, whose trajectories are chaotic: after
%% about 1.5 s every setting has diverged from the exact solution by metres,
%% which measures the chaos, not the method.
-spec default_scenes() -> [string()].
default_scenes() ->
    ["projectile", "ball_drop", "head_on_elastic", "newtons_cradle", "fast_thin_wall", "bouncing_50_250:1000"].

-spec default_substeps() -> [number()].
default_substeps() -> [0.5, 1, 2, 4, 8, 16].

%% Strides in ms, rounded up to a multiple of each substep.
-spec default_strides() -> [pos_integer()].
default_strides() -> [16, 64, 256].

%%% The sweep

%% Every setting of every scene, scenes in the order given, then substep,
%% integrator, CCD (off first) and stride; rows carry `pareto` (on their
%% scene's speed/position-error front). Scenes are checked before anything runs.
-spec sweep(options()) -> {ok, [row()]} | {error, string()}.
sweep(#{scenes := Specs} = Opts) ->
    Scenes = [case Spec of
                  {File, Until} -> {File, Opts#{until => Until}};
                  File -> {File, Opts}
              end || Spec <- Specs],
    case first_error([check_scene(F) || {F, _} <- Scenes]) of
        {error, _} = Error ->
            Error;
        ok ->
            try
                {ok, pareto(lists:append([sweep_scene(F, O) || {F, O} <- Scenes]))}
            catch
                throw:{accuracy_error, Msg} -> {error, Msg}
            end
    end.

first_error(Results) ->
    case [E || {error, _} = E <- Results] of
        [] -> ok;
        [E | _] -> E
    end.

%% Can the exact solver model this scene? Spheres without friction or
%% rotation, planes and boxes (cylinders are not modelled).
-spec check_scene(file:filename()) -> ok | {error, string()}.
check_scene(File) ->
    case rigidwarp:load(File, #{}) of
        {error, _} = Error ->
            Error;
        {ok, #scene{name = Name, model = #model{friction = F, rotation = R}, fixtures = Fixtures}} ->
            Cylinders = [Id || #fixture{id = Id, shape = {cylinder, _, _, _, _}} <- Fixtures],
            if
                F =/= undefined; R ->
                    fmt_error("~ts: the exact solver models spheres without friction or rotation", [Name]);
                Cylinders =/= [] ->
                    fmt_error("~ts: the exact solver does not model cylinders (~ts)", [Name, hd(Cylinders)]);
                true -> ok
            end
    end.

sweep_scene(File, #{substeps := Substeps, strides := Strides, integrators := Integrators, ccd := Ccds} = Opts) ->
    {ok, #scene{duration = Duration, frame = Frame, tick_us = Tick, model = #model{gravity = G}}} =
        rigidwarp:load(File, #{}),
    %% times in whole microseconds here, so that 0.5 ms substeps round up exactly
    UntilUs = case maps:find(until, Opts) of
                  {ok, U} -> us(U);
                  error -> Duration * Tick
              end,
    Frame0 = Frame * Tick,
    %% without gravity every integrator moves a body by v dt: the same frames
    Ints = case G of
               undefined -> lists:sublist(Integrators, 1);
               _ -> Integrators
           end,
    lists:append(
      [begin
           SUs = us(S),
           End = ms(round_up(UntilUs, SUs)),
           Exact = exact(File, SUs, End),
           lists:append(
             [begin
                  Setting = #{substep => S, integrator => I, ccd => C, until => End},
                  Acc = measure(File, Setting, Exact),
                  Rows = [begin
                              Speed = speed(File, Setting#{stride => St, frame_ms => ms(round_up(Frame0, SUs))}, Opts),
                              maps:merge(Acc, Speed#{substep_ms => S, stride_ms => St, integrator => I, ccd => C})
                          end || St <- lists:usort([ms(round_up(us(St0), SUs)) || St0 <- Strides])],
                  _ = [(maps:get(on_row, Opts, fun(_) -> ok end))(R) || R <- Rows],
                  Rows
              end || I <- Ints, C <- Ccds])
       end || S <- Substeps]).

round_up(X, S) -> S * ((X + S - 1) div S).

us(Ms) -> round(Ms * 1000).

%% Whole ms as integers, as frame times are.
ms(Us) -> rw_scene:us_to_ms(Us).

%% Time Warp with default schedulers: the fastest of at least MinRuns runs
%% that take at least MinWall ms together (the machine may be busy with
%% other work; the fastest run is the one least disturbed by it).
speed(File, #{substep := S, stride := St, frame_ms := F, until := End, integrator := I, ccd := C}, Opts) ->
    {ok, Scene} = load(File, #{substep => S, stride => St, frame_ms => F, until => End, integrator => I, ccd => C}),
    Best = speed_runs(Scene, maps:get(min_runs, Opts, 3), maps:get(min_wall_ms, Opts, 300), 0.0, infinity),
    #{scene => Scene#scene.name, sim_ms => End, wall_ms => Best, realtime_factor => End / max(Best, 0.001)}.

speed_runs(_Scene, Runs, MinWall, Total, Best) when Runs =< 0, Total >= MinWall; Runs =< -100 ->
    Best;
speed_runs(#scene{name = Name} = Scene, Runs, MinWall, Total, Best) ->
    T0 = erlang:monotonic_time(microsecond),
    case rigidwarp:run_scene(Scene, #{engine => timewarp}) of
        {ok, _} -> ok;
        {error, Msg} -> throw({accuracy_error, lists:flatten(io_lib:format("~ts: ~ts", [Name, Msg]))})
    end,
    Wall = (erlang:monotonic_time(microsecond) - T0) / 1000.0,
    speed_runs(Scene, Runs - 1, MinWall, Total + Wall, min(Best, Wall)).

load(File, Opts) ->
    case rigidwarp:load(File, Opts) of
        {ok, _} = Ok -> Ok;
        {error, Msg} -> throw({accuracy_error, Msg})
    end.

%%% Accuracy of one setting

%% The exact solution at every multiple of the substep (SUs, in us) up to End ms.
exact(File, SUs, End) ->
    {ok, #scene{name = Name, model = #model{gravity = G, restitution = E}, spheres = Spheres, initial = Initial,
                fixtures = Fixtures}} = load(File, #{}),
    World = #{gravity => G, restitution => E,
              planes => lists:append([rw_exact:walls(Shape) || #fixture{shape = Shape} <- Fixtures])},
    Bodies = [#{id => Id, r => R, m => M, p => P, v => V}
              || {#sphere{id = Id, radius = R, mass = M}, #st{p = P, v = V}} <- lists:zip(Spheres, Initial)],
    try rw_exact:run(World, Bodies, [ms(T) || T <- lists:seq(0, us(End), SUs)])
    catch error:Reason -> throw({accuracy_error, lists:flatten(io_lib:format("~ts: the exact solver stopped: ~0p",
                                                                            [Name, Reason]))})
    end.

%% Runs one setting (substep, integrator, ccd, until) on the reference
%% engine with a frame at every substep and compares it with Exact
%% (rw_exact:run/3 at the same times).
-spec measure(file:filename(), #{substep := number(), integrator := rw_integrate:integrator(),
                                 ccd := boolean(), until := number()},
              {[rw_exact:frame()], list()}) -> accuracy().
measure(File, #{substep := S, integrator := I, ccd := C, until := End}, Exact) ->
    {ok, Scene} = load(File, #{substep => S, stride => S, frame_ms => S, until => End, integrator => I, ccd => C}),
    Self = self(),
    Ref = make_ref(),
    {ok, _} = rigidwarp:run_scene(Scene, #{engine => reference, on_frame => fun(F) -> Self ! {Ref, F} end}),
    metrics(Scene, drain(Ref), Exact).

drain(Ref) -> receive {Ref, F} -> [F | drain(Ref)] after 0 -> [] end.

%% The metrics of engine Frames (every substep, in order) against the
%% exact solution at the same times.
-spec metrics(#scene{}, [rw_reference:frame()], {[rw_exact:frame()], list()}) -> accuracy().
metrics(#scene{model = #model{gravity = G, restitution = Rest}, spheres = Spheres, fixtures = Fixtures}, Frames, {ExactFrames, Events}) ->
    length(Frames) =:= length(ExactFrames) orelse error({frames_differ, length(Frames), length(ExactFrames)}),
    Mass = [M || #sphere{mass = M} <- Spheres],
    Radius = [R || #sphere{radius = R} <- Spheres],
    Pairs = lists:zip(Frames, ExactFrames),
    Errors = lists:append([[rw_vec:len(rw_vec:sub(P, Pe)) || {{_, P, _, _, _}, {_, Pe, _}} <- lists:zip(Bs, Es)]
                           || {{frame, T, Bs}, {T, Es}} <- Pairs]),
    length(Errors) =:= length(Frames) * length(Spheres) orelse error(frame_times_differ),
    Energy = fun(Bs) -> lists:sum([M * (0.5 * rw_vec:len2(V) - gdot(G, P)) || {M, {_, P, V, _, _}} <- lists:zip(Mass, Bs)]) end,
    Momentum = fun(Bs) -> lists:foldl(fun({M, {_, _, V, _, _}}, Acc) -> rw_vec:madd(Acc, V, M) end, rw_vec:zero(),
                                      lists:zip(Mass, Bs)) end,
    EScale = lists:max([1.0e-300 | [lists:sum([0.5 * M * rw_vec:len2(V) || {M, {_, _, V}} <- lists:zip(Mass, Es)])
                                    || {_, Es} <- ExactFrames]]),
    PScale = lists:max([1.0e-300 | [lists:sum([M * rw_vec:len(V) || {M, {_, _, V}} <- lists:zip(Mass, Es)])
                                    || {_, Es} <- ExactFrames]]),
    [{frame, 0, Bs0} | _] = Frames,
    E0 = Energy(Bs0),
    P0 = Momentum(Bs0),
    Gravity = case G of undefined -> rw_vec:zero(); _ -> rw_vec:scale(G, lists:sum(Mass)) end,
    %% conserved quantities only: energy at restitution 1, momentum (less
    %% gravity's M g t) without fixtures
    EnergyDrift = case Rest of
                      1.0 -> lists:max([abs(Energy(Bs) - E0) / EScale || {frame, _, Bs} <- Frames]);
                      _ -> undefined
                  end,
    MomentumDrift = case Fixtures of
                        [] -> lists:max([rw_vec:len(rw_vec:sub(Momentum(Bs), rw_vec:madd(P0, Gravity, T / 1000)))
                                         / PScale || {frame, T, Bs} <- Frames]);
                        _ -> undefined
                    end,
    Shapes = [Shape || #fixture{shape = Shape} <- Fixtures],
    {Depth, Missed} = contacts(Frames, Radius, Shapes),
    #{pos_err_max => lists:max(Errors),
      pos_err_rms => math:sqrt(lists:sum([E * E || E <- Errors]) / length(Errors)),
      energy_drift => EnergyDrift, momentum_drift => MomentumDrift,
      max_penetration => Depth, missed => Missed, impacts => length(Events)}.

gdot(undefined, _) -> 0.0;
gdot(G, P) -> rw_vec:dot(G, P).

engine_p(Bs) -> [P || {_, P, _, _, _} <- Bs].

%% Deepest penetration in any frame, and missed collisions between
%% consecutive frames (see the module comment).
contacts([{frame, _, Bs0} | Rest], Radius, Shapes) ->
    {_, Depth, Missed} =
        lists:foldl(fun({frame, _, Bs1}, {Prev, D, M}) ->
                            {D1, M1} = substep(Prev, engine_p(Bs1), Radius, Shapes),
                            {engine_p(Bs1), max(D, D1), M + M1}
                    end, {engine_p(Bs0), 0.0, 0}, Rest),
    {Depth, Missed}.

substep(P0s, P1s, Radius, Shapes) ->
    Bodies = lists:zip3(P0s, P1s, Radius),
    Fixture = [{fixture_depth(P1, R, Shape), crosses(P0, P1, Shape)}
               || {P0, P1, R} <- Bodies, Shape <- Shapes],
    %% sweep and prune on x over the span each sphere covers in the substep
    Spans = [{min(X0, X1) - R, K, max(X0, X1) + R}
             || {K, {{X0, _, _}, {X1, _, _}, R}} <- lists:zip(lists:seq(1, length(Bodies)), Bodies)],
    ByK = list_to_tuple(Bodies),
    Pair = [pair(element(A, ByK), element(B, ByK)) || {A, B} <- rw_broadphase:sweep(Spans, spans)],
    {lists:max([0.0 | [D || {D, _} <- Fixture ++ Pair]]),
     length([x || {_, true} <- Fixture ++ Pair])}.

pair({PA0, PA1, RA}, {PB0, PB1, RB}) ->
    D0 = rw_vec:sub(PB0, PA0),
    D1 = rw_vec:sub(PB1, PA1),
    Sum = RA + RB,
    Depth = Sum - rw_vec:len(D1),
    {max(0.0, Depth), rw_vec:dot(D0, D1) < 0.0 andalso segment_distance(D0, D1) < Sum}.

%% Distance from the origin to the segment D0 -> D1.
segment_distance(D0, D1) ->
    Dd = rw_vec:sub(D1, D0),
    L2 = rw_vec:len2(Dd),
    S = case L2 > 0.0 of
            true -> max(0.0, min(1.0, -rw_vec:dot(D0, Dd) / L2));
            false -> 0.0
        end,
    rw_vec:len(rw_vec:madd(D0, Dd, S)).

fixture_depth(P, R, Shape) ->
    lists:max([0.0 | [D || {_, #contact{depth = D}} <- rw_narrow:sphere_fixture(P, R, Shape)]]).

%% Did the centre go from the free side of the fixture's surface into or
%% through its solid during the substep?
crosses(P0, P1, {plane, N, Off}) ->
    rw_vec:dot(N, P0) >= Off andalso rw_vec:dot(N, P1) < Off;
crosses(P0, P1, {box, _, _, hollow} = Box) ->
    lists:any(fun({N, Off}) -> crosses(P0, P1, {plane, N, Off}) end, rw_exact:walls(Box));
crosses(P0, P1, {box, C, E, solid}) ->
    Lo = rw_vec:sub(C, E),
    Hi = rw_vec:add(C, E),
    not inside(P0, Lo, Hi) andalso segment_hits_box(P0, rw_vec:sub(P1, P0), Lo, Hi).

inside({X, Y, Z}, {LX, LY, LZ}, {HX, HY, HZ}) ->
    X > LX andalso X < HX andalso Y > LY andalso Y < HY andalso Z > LZ andalso Z < HZ.

%% Does P + s D, s in [0, 1], meet the open box (Lo, Hi)?
segment_hits_box(P, D, Lo, Hi) -> rw_narrow:segment_box(P, D, Lo, Hi, open) =/= none.

%%% Pareto front, CSV and the table

%% Marks each row `pareto` when no other row of its scene is at least as
%% fast and at least as accurate (position error) and better in one.
-spec pareto([row()]) -> [row()].
pareto(Rows) ->
    [R#{pareto => not lists:any(fun(O) -> dominates(O, R) end, [O || #{scene := S} = O <- Rows,
                                                                     S =:= maps:get(scene, R)])}
     || R <- Rows].

dominates(#{realtime_factor := FA, pos_err_max := EA}, #{realtime_factor := FB, pos_err_max := EB}) ->
    FA >= FB andalso EA =< EB andalso (FA > FB orelse EA < EB).

%% CSV column names, in order.
-spec columns() -> [atom()].
columns() ->
    [scene, substep_ms, stride_ms, integrator, ccd, sim_ms, wall_ms, realtime_factor, pos_err_max, pos_err_rms,
     energy_drift, momentum_drift, max_penetration, missed, impacts, pareto].

-spec csv([row()]) -> iodata().
csv(Rows) ->
    [lists:join(",", [atom_to_list(C) || C <- columns()]), "\n",
     [[lists:join(",", [csv_value(maps:get(C, R, false)) || C <- columns()]), "\n"] || R <- Rows]].

%% One value as CSV (and the table) writes it: 0.5, 16, true as 1.
csv_value(undefined) -> "";
csv_value(B) when is_binary(B) -> B;
csv_value(true) -> "1";
csv_value(false) -> "0";
csv_value(A) when is_atom(A) -> atom_to_list(A);
csv_value(I) when is_integer(I) -> integer_to_list(I);
csv_value(F) when is_float(F) -> float_to_list(F, [short]).

%% A table for people: aligned columns, numbers to 3 significant digits,
%% `*` marking the Pareto front of each scene.
-spec table([row()]) -> iodata().
table(Rows) ->
    Header = ["scene", "substep", "stride", "integrator", "ccd", "realtime", "pos err max", "pos err rms",
              "energy", "momentum", "penetration", "missed", "impacts", "front"],
    Cells = [[binary_to_list(S), csv_value(Dt), csv_value(St), atom_to_list(I), on_off(C),
              num(Rt), num(EMax), num(ERms), num(En), num(Mo), num(Pen), integer_to_list(Mi), integer_to_list(Im),
              case maps:get(pareto, R, false) of true -> "*"; false -> "" end]
             || #{scene := S, substep_ms := Dt, stride_ms := St, integrator := I, ccd := C, realtime_factor := Rt,
                  pos_err_max := EMax, pos_err_rms := ERms, energy_drift := En, momentum_drift := Mo,
                  max_penetration := Pen, missed := Mi, impacts := Im} = R <- Rows],
    Widths = [lists:max([string:length(X) || X <- Col]) || Col <- transpose([Header | Cells])],
    Left = [true, false, false, true, true, false, false, false, false, false, false, false, false, true],
    Scenes = [none | [S || #{scene := S} <- Rows]],
    %% a blank line between scenes
    [[[case Prev =:= This of true -> ""; false -> "\n" end || This =/= none, Prev =/= none],
      string:trim(lists:join("  ", [pad(X, W, L) || {X, W, L} <- lists:zip3(Line, Widths, Left)]), trailing), "\n"]
     || {Prev, This, Line} <- lists:zip3([none | lists:droplast(Scenes)], Scenes, [Header | Cells])].

on_off(true) -> "on";
on_off(false) -> "off".

pad(X, W, true) -> string:pad(X, W, trailing);
pad(X, W, false) -> string:pad(X, W, leading).

transpose([[] | _]) -> [];
transpose(Rows) -> [[hd(R) || R <- Rows] | transpose([tl(R) || R <- Rows])].

%% 3 significant digits: 0, 12.3, 0.123, 4.57e-3 (- for undefined).
-spec num(number() | undefined) -> string().
num(undefined) -> "-";
num(X) when X == 0 -> "0";
num(X) when abs(X) < 0.01; abs(X) >= 1.0e5 ->
    [M, E] = string:split(io_lib:format("~.3e", [float(X)]), "e"),
    M ++ "e" ++ integer_to_list(list_to_integer(E));
num(X) ->
    Digits = max(0, 2 - floor(math:log10(abs(X)))),
    float_to_list(float(X), [{decimals, Digits}]).

fmt_error(Fmt, Args) -> {error, lists:flatten(io_lib:format(Fmt, Args))}.
