%% What a scene may ask of the engines, checked before anything starts
%% (pure; rw_scene and rigidwarp call it). A scene outside these limits
%% would not fail cleanly later: it would overflow a float (badarith) or
%% list cells until the machine runs out of memory.
%%
%% * Radii and masses within ranges that keep the inverse inertia
%%   2.5 / (m r^2) finite and above zero.
%% * Cells at least an eighth of the largest radius: a sphere's box then
%%   holds at most 18 cells per axis.
%% * Cell indices below 2^53 over the whole run, in the scene's cells and
%%   in the reference engine's (two radii of the largest sphere).
%% * With CCD, at any speed a body can reach (speed_bounds/3): no sweep
%%   listing more than rw_hash:max_swept_cells/0 cells in a substep, in
%%   either engine's cells, and no Time Warp write of a stride of sweeps
%%   covering more than rw_tvht_plan:max_write_cells/0.
%% * Bucket processes that fit the VM's process limit beside the bodies.
-module(rw_scene_limits).
-include("rigidwarp.hrl").
-export([radius/1, mass/1, check/4, speed_bounds/3, buckets/4]).
-export_type([sphere_at/0]).

%% A sphere of the scene with its initial state and its JSON path.
-type sphere_at() :: {#sphere{}, #st{}, [binary() | non_neg_integer()]}.

-define(MIN_RADIUS, 1.0e-9).
-define(MIN_MASS, 1.0e-20).
%% rw_scene:max_abs/0: no number of a scene is larger.
-define(MAX, 1.0e12).
%% The cell size may be this fraction of the largest radius.
-define(CELL_PER_RADIUS, 8).
%% Cell indices stay below this: a double counts every integer up to it.
-define(MAX_INDEX, 9007199254740992.0).
%% Speed bounds are raised by this share for the energy that rounding and
%% the explicit Euler integrator add.
-define(SPEED_MARGIN, 1.1).
%% Processes kept free beside bodies and buckets: a simulation's own
%% (run, supervisors, tables, GVT, sweeper, watchdog) and the caller's.
-define(SPARE_PROCESSES, 1000).

%% A sphere's radius in metres.
-spec radius(float()) -> ok | {error, string()}.
radius(R) -> range(R, ?MIN_RADIUS, "m").

%% A sphere's mass in kilograms.
-spec mass(float()) -> ok | {error, string()}.
mass(M) -> range(M, ?MIN_MASS, "kg").

range(X, Min, _Unit) when X >= Min, X =< ?MAX -> ok;
range(X, Min, Unit) ->
    {error, fmt("must be from ~s to ~s ~s (the inverse inertia 2.5 / (m r^2) stays finite), got ~s",
                [num(Min), num(?MAX), Unit, num(X)])}.

%% The scene's spheres (radii and masses within range), its cell size, its
%% model, how long it runs in seconds and how many substeps a stride
%% holds (at most the whole run): ok, or the JSON path and the problem.
-spec check([sphere_at(), ...], float(), #model{}, {float(), pos_integer()}) ->
          ok | {error, [binary() | non_neg_integer()], string()}.
check(Spheres, CellSize, #model{ccd = Ccd} = Model, {Seconds, _StrideSubsteps} = Times) ->
    MaxR = lists:max([R || {#sphere{radius = R}, _, _} <- Spheres]),
    case CellSize >= MaxR / ?CELL_PER_RADIUS of
        false ->
            {error, [<<"cell_size">>],
             fmt("must be at least 1/~b of the largest radius (~s m here), so that a sphere's box holds at most "
                 "~b cells per axis, got ~s", [?CELL_PER_RADIUS, num(MaxR / ?CELL_PER_RADIUS), 2 * ?CELL_PER_RADIUS + 2,
                                                num(CellSize)])};
        true ->
            Bounds = speed_bounds(Spheres, Model, Seconds),
            Cells = [{CellSize, "cell_size"}, {2.0 * MaxR, "the reference engine's cells: two radii of the largest sphere"}],
            first([fun() -> indices(Spheres, Bounds, Cells, Seconds) end,
                   fun() when Ccd -> sweeps(Spheres, Bounds, Cells, Model, Times);
                      () -> ok
                   end])
    end.

first([]) -> ok;
first([Check | Rest]) ->
    case Check() of
        ok -> first(Rest);
        Error -> Error
    end.

%% A bound on the speed of each sphere (in order) at any time of a run of
%% Seconds, from energy: contacts conserve or lose kinetic energy (linear
%% and rotational), so the whole scene's, E, may end in one sphere, of
%% mass m: v <= sqrt(2 E / m). Gravity (g) adds what the bodies' falls
%% release: with M the total mass, their fall in a moment is at most
%% g sum(m_j v_j) <= g sqrt(2 M K) (Cauchy-Schwarz) for a kinetic energy
%% K, so sqrt(K) grows by at most g sqrt(M / 2) per second, and
%% v <= sqrt(2 E / m) + g t sqrt(M / m). (One body: its speed plus g t. A
%% light ball on a heavy one, both falling, can leave faster than g t:
%% sqrt(M / m) says how much.) Raised by a tenth, and by a substep's
%% gravity, for rounding, for the energy explicit Euler adds, and for the
%% little that impulses summed at a substep where a sphere meets two
%% others can add; physics that gains more (a run away) meets the caps of
%% rw_hash and rw_tvht_plan at run time, which stop the run.
-spec speed_bounds([sphere_at()], #model{}, float()) -> [float()].
speed_bounds(Spheres, #model{gravity = Gravity, dt = Dt}, Seconds) ->
    Energy = lists:sum([kinetic(S, St) || {S, St, _} <- Spheres]),
    Total = lists:sum([M || {#sphere{mass = M}, _, _} <- Spheres]),
    G = case Gravity of undefined -> 0.0; _ -> rw_vec:len(Gravity) end,
    [?SPEED_MARGIN * (math:sqrt(2.0 * Energy / M) + G * Seconds * math:sqrt(Total / M)) + G * Dt
     || {#sphere{mass = M}, _, _} <- Spheres].

kinetic(#sphere{mass = M, radius = R}, #st{v = V, w = W}) ->
    Spin = case W of
               undefined -> 0.0;
               _ -> 0.5 * 0.4 * M * R * R * rw_vec:len2(W)
           end,
    0.5 * M * rw_vec:len2(V) + Spin.

%% How far from the origin each sphere may get: its start, and its speed
%% bound for the whole run.
reach(#st{p = P}, Speed, Seconds) -> rw_vec:max_abs(P) + Speed * Seconds.

indices(Spheres, Bounds, Cells, Seconds) ->
    Far = [{Reach / S, Sphere, Speed, Reach, Cell}
           || {{_, St, _} = Sphere, Speed} <- lists:zip(Spheres, Bounds), Reach <- [reach(St, Speed, Seconds)],
              {S, _} = Cell <- Cells],
    case lists:max(Far) of
        {Index, {#sphere{id = Id}, _, Path}, Speed, Reach, {S, Which}} when Index >= ?MAX_INDEX ->
            Remedy = case Which of
                         "cell_size" -> "make cell_size larger";
                         _ -> "make the largest sphere larger"
                     end,
            {error, Path ++ [<<"position">>],
             fmt("sphere ~s may get ~s m from the origin (its start, then up to ~s m/s for ~s s): ~s cells of ~s m "
                 "(~s), and cell indices must stay below 2^53; bring the scene nearer the origin or ~s",
                 [Id, num(Reach), num(Speed), num(Seconds), num(Index), num(S), Which, Remedy])};
        _ -> ok
    end.

%% With CCD, the most cells a sphere's sweep lists in a substep, at its
%% speed bound, in the scene's cells and in the reference's, and the most
%% a Time Warp write of a stride of such substeps covers in the scene's.
sweeps(Spheres, Bounds, [{CellSize, _} | _] = Cells, #model{dt = Dt, gravity = Gravity}, {Seconds, Substeps}) ->
    G = case Gravity of undefined -> 0.0; _ -> rw_vec:len(Gravity) end,
    SubstepCap = rw_hash:max_swept_cells(),
    WriteCap = rw_tvht_plan:max_write_cells(),
    Worst = lists:max(
              [{Count / Cap, Count, Cap, Kind, Sphere, Speed, Move, Cell}
               || {{#sphere{radius = R}, St, _} = Sphere, Speed} <- lists:zip(Spheres, Bounds),
                  Move <- [Speed * Dt + G * Dt * Dt],
                  {S, _} = Cell <- Cells,
                  PerSubstep <- [rw_hash:sweep_bound(Move, R, S, reach(St, Speed, Seconds))],
                  {Count, Cap, Kind} <- [{PerSubstep, SubstepCap, substep}
                                         | [{PerSubstep * Substeps, WriteCap, write} || S =:= CellSize]]]),
    case Worst of
        {Over, Count, Cap, Kind, {#sphere{id = Id}, _, Path}, Speed, Move, {S, Which}} when Over > 1.0 ->
            Energy = case G > 0.0 of
                         true -> fmt(", and what gravity adds over ~s s", [num(Seconds)]);
                         false -> ""
                     end,
            Covered = case Kind of
                          substep -> fmt("whose sweep lists up to ~s cells of ~s m (~s), more than the ~b a sweep "
                                         "may list", [num(Count), num(S), Which, Cap]);
                          write -> fmt("whose sweeps over a stride of ~b substeps cover up to ~s cells of ~s m (~s), "
                                       "more than the ~b one write to the Time Warp engine's TVHT may cover",
                                       [Substeps, num(Count), num(S), Which, Cap])
                      end,
            Remedies = ["lower the speeds"]
                ++ [case Kind of substep -> "the substep"; write -> "the stride" end]
                ++ ["the duration" || G > 0.0]
                ++ ["make cell_size larger" || Which =:= "cell_size"]
                ++ ["turn CCD off"],
            {error, Path,
             fmt("with CCD, sphere ~s could reach ~s m/s (all of the scene's kinetic energy in it~s): a move of "
                 "~s m in a ~s ms substep, ~s; ~s", [Id, num(Speed), Energy, num(Move), ms(Dt), Covered,
                                                      lists:join(", ", lists:droplast(Remedies)) ++ " or "
                                                      ++ lists:last(Remedies)])};
        _ -> ok
    end.

%% Buckets bucket processes and Bodies body processes in a VM of Limit
%% processes, InUse of them running: ok, or why they do not fit.
-spec buckets(pos_integer(), non_neg_integer(), pos_integer(), non_neg_integer()) -> ok | {error, string()}.
buckets(Buckets, Bodies, Limit, InUse) ->
    Max = Limit - InUse - Bodies - ?SPARE_PROCESSES,
    case Buckets =< Max of
        true -> ok;
        false ->
            {error, fmt("~b buckets and ~b ~s need ~b processes, more than this VM's process limit of ~b allows "
                        "(~b running, ~b kept spare): at most ~b buckets here, or raise the limit (erl +P)",
                        [Buckets, Bodies, case Bodies of 1 -> "body"; _ -> "bodies" end, Buckets + Bodies, Limit,
                         InUse, ?SPARE_PROCESSES, max(0, Max)])}
    end.

%% A number as people read it: 0.5, 1.0e-9, 1.10e+8 (three digits at most).
num(X) when is_integer(X) -> integer_to_list(X);
num(X) ->
    case float_to_list(X, [short]) of
        Short when length(Short) =< 9 -> Short;
        _ -> string:trim(io_lib:format("~.3g", [X]))
    end.

%% Seconds as whole milliseconds where they are.
ms(Seconds) ->
    Ms = Seconds * 1000.0,
    case Ms == round(Ms) of
        true -> integer_to_list(round(Ms));
        false -> num(Ms)
    end.

fmt(Format, Args) -> lists:flatten(io_lib:format(Format, Args)).
