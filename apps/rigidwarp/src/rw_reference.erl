%% The sequential reference engine: plain, frame-centric, one process. For
%% each substep it finds every contact among the pre-response states of that
%% substep, sums each body's contact effects in canonical order of partner,
%% and integrates. It is the oracle the Time Warp engine must equal bit for
%% bit, so it is kept simple enough to trust by reading.
-module(rw_reference).
-include("rigidwarp.hrl").
-export([run/2, substep/3]).
-export_type([frame/0, body_frame/0, checkpoint/0, stats/0, options/0]).

%% A committed frame: each dynamic body's position and post-response
%% velocities at time T, sorted by id.
-type body_frame() :: {Id :: binary(), P :: rw_vec:vec(), V :: rw_vec:vec(),
                       Q :: rw_quat:quat() | undefined, W :: rw_vec:vec() | undefined}.
%% T is in ms: an integer when whole (always, with a 1 ms tick).
-type frame() :: {frame, T :: number(), [body_frame()]}.
%% Everything the future of a run depends on at frame time Ms (Tick in the
%% scene's ticks): every body's pre-response state, in scene order. A run
%% started from it (rw_scene:from_checkpoint/2) writes, from the frame at Ms
%% on, the frames of the run that never stopped.
-type checkpoint() :: {checkpoint, Tick :: non_neg_integer(), Ms :: number(), [#st{}]}.
-type stats() :: #{substeps := non_neg_integer(), body_substeps := non_neg_integer(),
                   pair_contacts := non_neg_integer(), fixture_contacts := non_neg_integer(),
                   frames := non_neg_integer(), sim_ms := number()}.
%% on_checkpoint: called after the frame of the same time, at frame times
%% at least checkpoint_ms (default 500) of wall time apart.
-type options() :: #{on_frame => fun((frame()) -> any()), on_checkpoint => fun((checkpoint()) -> any()),
                     checkpoint_ms => non_neg_integer()}.

-spec run(#scene{}, options()) -> {ok, stats()}.
run(#scene{duration = End, substep = Dt, frame = Frame, spheres = Spheres, initial = Initial, start = T0} = Scene,
    Opts) ->
    OnFrame0 = maps:get(on_frame, Opts, fun(_) -> ok end),
    OnCheckpoint = maps:get(on_checkpoint, Opts, none),
    Every = maps:get(checkpoint_ms, Opts, ?CHECKPOINT_MS),
    %% frames leave the engine with their time in ms; the accumulator is
    %% when the next checkpoint is due (monotonic ms)
    OnFrame = fun({frame, T, Bodies}, States, Due) ->
                      Ms = rw_scene:ms(Scene, T),
                      OnFrame0({frame, Ms, Bodies}),
                      checkpoint(OnCheckpoint, Every, Due, {checkpoint, T, Ms, tuple_to_list(States)})
              end,
    Bodies = list_to_tuple(Spheres),
    Stats0 = #{substeps => 0, body_substeps => 0, pair_contacts => 0, fixture_contacts => 0,
               frames => 0, sim_ms => rw_scene:duration_ms(Scene) - rw_scene:ms(Scene, T0)},
    {ok, #{substeps := Last} = Stats} = loop(T0, End, Dt, Frame, own_grid(Scene), Bodies, list_to_tuple(Initial),
                                             {OnFrame, erlang:monotonic_time(millisecond) + Every}, Stats0),
    {ok, Stats#{substeps := Last - T0 div Dt}}.

checkpoint(none, _Every, Due, _Checkpoint) -> Due;
checkpoint(Fun, Every, Due, Checkpoint) ->
    Now = erlang:monotonic_time(millisecond),
    case Now >= Due of
        true ->
            _ = Fun(Checkpoint),
            Now + Every;
        false -> Due
    end.

%% The scene's cell size is the TVHT's. The reference rebuilds its grid
%% every substep and checks every pair sharing a cell, for which cells of
%% 2 radii are faster; the grid never changes which contacts are found, only
%% how many pairs are checked, and the baseline should be at its best.
own_grid(#scene{spheres = []} = Scene) -> Scene;
own_grid(#scene{spheres = Spheres} = Scene) ->
    Scene#scene{cell_size = 2.0 * lists:max([R || #sphere{radius = R} <- Spheres])}.

loop(T, End, Dt, FrameT, Scene, Bodies, States, {OnFrame, Acc} = Out, Stats) ->
    Frame = T rem FrameT =:= 0 orelse T =:= End,
    {Next, Post, Counts} = substep(Scene, Bodies, States),
    Stats1 = maps:map(fun(K, V) -> V + maps:get(K, Counts, 0) end, Stats),
    {Stats2, Out1} = case Frame of
                         true ->
                             {maps:update_with(frames, fun(F) -> F + 1 end, Stats1),
                              {OnFrame, OnFrame({frame, T, frame_bodies(Bodies, States, Post)}, States, Acc)}};
                         false -> {Stats1, Out}
                     end,
    case T >= End of
        true -> {ok, Stats2#{substeps := T div Dt}};
        false -> loop(T + Dt, End, Dt, FrameT, Scene, Bodies, Next, Out1, Stats2)
    end.

frame_bodies(Bodies, States, Post) ->
    [begin
         #sphere{id = Id} = element(K, Bodies),
         #st{p = P, q = Q} = element(K, States),
         {V, W, _U} = element(K, Post),
         {Id, P, V, Q, W}
     end || K <- lists:seq(1, tuple_size(Bodies))].

%% One substep for every body: returns the next states, the post-response
%% velocities at this substep and counters.
-spec substep(#scene{}, tuple(), tuple()) -> {tuple(), tuple(), map()}.
substep(#scene{model = #model{ccd = Ccd} = M, fixtures = Fixtures, cell_size = Cell}, Bodies, States) ->
    N = tuple_size(Bodies),
    Disp = case Ccd of
               true -> list_to_tuple([rw_integrate:free_displacement(M, element(K, States))
                                      || K <- lists:seq(1, N)]);
               false -> undefined
           end,
    Pairs = candidate_pairs(Bodies, States, Disp, Cell),
    %% fixture contacts first: pairs see the velocities after them
    Ks = lists:seq(1, N),
    Fixed = [rw_dynamics:fixture_effects(M, element(K, Bodies), element(K, States), Fixtures) || K <- Ks],
    Seen = list_to_tuple([rw_dynamics:after_fixtures(element(K, States), F) || {K, F} <- lists:zip(Ks, Fixed)]),
    Effects0 = maps:from_list(lists:zip(Ks, Fixed)),
    NFixture = length(lists:append(Fixed)),
    {Effects, NPairs} =
        lists:foldl(
          fun({A, B}, {Acc, C}) ->
                  SA = element(A, Bodies), SB = element(B, Bodies),
                  case pair_contact(SA, element(A, States), SB, element(B, States), A, B, Disp) of
                      none -> {Acc, C};
                      Contact ->
                          {EA, EB} = rw_response:pair(M, SA, element(A, Seen), SB, element(B, Seen), Contact),
                          Acc1 = maps:update_with(A, fun(L) -> [{{SB#sphere.idx, 0}, EA} | L] end, Acc),
                          {maps:update_with(B, fun(L) -> [{{SA#sphere.idx, 0}, EB} | L] end, Acc1), C + 1}
                  end
          end, {Effects0, 0}, Pairs),
    Results = [begin
                   St = element(K, States),
                   Sorted = [E || {_, E} <- lists:keysort(1, maps:get(K, Effects))],
                   {V, W, U} = rw_dynamics:respond(St, Sorted),
                   {rw_integrate:advance(M, St, V, W, U), {V, W, U}}
               end || K <- lists:seq(1, N)],
    {list_to_tuple([S || {S, _} <- Results]), list_to_tuple([P || {_, P} <- Results]),
     #{body_substeps => N, pair_contacts => NPairs, fixture_contacts => NFixture}}.

pair_contact(#sphere{radius = RA}, #st{p = PA}, #sphere{radius = RB}, #st{p = PB}, _A, _B, undefined) ->
    rw_narrow:sphere_sphere(PA, RA, PB, RB);
pair_contact(#sphere{radius = RA}, #st{p = PA}, #sphere{radius = RB}, #st{p = PB}, A, B, Disp) ->
    rw_narrow:swept_sphere_sphere(PA, element(A, Disp), RA, PB, element(B, Disp), RB).

%% Pairs (lower position first) whose spheres (swept, with CCD) share a
%% cell of the grid.
candidate_pairs(Bodies, States, Disp, Cell) ->
    BoxOf = fun(K) ->
                    #sphere{radius = R} = element(K, Bodies),
                    #st{p = P} = element(K, States),
                    case Disp of
                        undefined -> rw_shape:sphere_aabb(P, R);
                        _ -> {swept, P, element(K, Disp), R}
                    end
            end,
    lists:sort(rw_broadphase:grid(tuple_size(Bodies), BoxOf, Cell)).
