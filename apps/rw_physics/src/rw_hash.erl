%% Volumetric hashing: which integer cells of Z^3 a box touches, and which
%% bucket of a pool owns a cell. Cells are unbounded (bignums far away).
-module(rw_hash).
-export([cells/2, swept_cells/4, cut/1, cell_of/2, bucket/2, box/2, box_cells/1, box_size/1, region/2, no_region/0,
         in_region/2, max_swept_cells/0, sweep_bound/4]).
-export_type([cell/0, box/0, region/0, extent/0]).

-type cell() :: {integer(), integer(), integer()}.
%% The integer ranges of cells an AABB touches: {X0, X1, Y0, Y1, Z0, Z1}.
-type box() :: {integer(), integer(), integer(), integer(), integer(), integer()}.
%% Where an AABB's corners may lie for box/2 to give the same box: for each
%% axis, the range of the low corner and of the high corner, shrunk by a
%% margin far above rounding, {Lo0, Lo1, Hi0, Hi1} per axis in x, y, z order.
-type region() :: {float(), float(), float(), float(), float(), float(),
                   float(), float(), float(), float(), float(), float()}.

%% What a body covers over a substep: a box, or a sphere of radius R whose
%% centre moves from P by D (with CCD).
-type extent() :: rw_shape:aabb() | {swept, P :: rw_vec:vec(), D :: rw_vec:vec(), R :: float()}.

%% A swept sphere whose box holds more cells than this is covered by the
%% boxes of pieces of its move instead (swept_cells/4).
-define(FEW_CELLS, 27).

%% The most cells swept_cells/4 lists for one sphere and substep: the
%% reference lists them all at every substep (a few MB at this cap). The
%% Time Warp engine keeps a stride of substeps in one write and bounds
%% writes apart (rw_tvht_plan:max_write_cells/0). The fastest sweeps of
%% the tests and benchmarks (5 km/s in 16 ms substeps, 17 km/s in 1 ms,
%% across the reference's cells of 0.1 m) are bounded by some 56,000 and
%% 12,000 at validation (rw_scene_limits).
-define(MAX_SWEPT_CELLS, 65536).

%% Every cell of side CellSize that the extent touches, in lexicographic
%% order (the order in which the TVHT locks them, Lemma 1): a box's cells,
%% or a swept sphere's (swept_cells/4).
-spec cells(extent(), float()) -> [cell()].
cells({swept, P, D, R}, S) -> swept_cells(P, D, R, S);
cells(AABB, S) -> box_cells(box(AABB, S)).

%% Does swept_cells/4 cut a move whose swept box is Box into pieces?
-spec cut(box()) -> boolean().
cut(Box) -> box_size(Box) > ?FEW_CELLS.

%% The cells of the box of a sphere of radius R whose centre moves from P
%% by D that the sphere can touch on the way, in lexicographic order. A box
%% of few cells is taken whole. A longer move is cut into pieces at most a
%% cell or a diameter long along every axis, and each piece's box (padded
%% far above the rounding of the points that cut them) is taken: along a
%% diagonal the swept box's cells grow as the cube of the move's length,
%% the pieces' as its length. A sphere touches nothing at any point of its
%% move outside the cells of the piece it is on, so two swept spheres that
%% touch share a cell of both covers, as they share one of both boxes.
%% The pieces' cells are counted before any is listed: past
%% max_swept_cells/0 the sweep raises error({too_many_cells, Message}).
-spec swept_cells(rw_vec:vec(), rw_vec:vec(), float(), float()) -> [cell()].
swept_cells({X, Y, Z} = P, {DX, DY, DZ} = D, R, S) ->
    {X0, X1, Y0, Y1, Z0, Z1} = Box = box(rw_shape:swept_aabb(P, D, R), S),
    case cut(Box) of
        false -> box_cells(Box);
        true ->
            Step = max(S, 2.0 * R),
            Move = rw_vec:max_abs(D),
            %% every piece holds a cell: too many pieces are refused
            %% before they are counted
            Move =< Step * ?MAX_SWEPT_CELLS orelse too_many(R, Move, S),
            K = trunc(Move / Step) + 1,
            Pad = pad(rw_vec:max_abs(P), Move, R),
            At = fun(I) when I =:= K -> {X + DX, Y + DY, Z + DZ};
                    (I) -> F = I / K, {X + DX * F, Y + DY * F, Z + DZ * F}
                 end,
            Pieces = [begin
                          {{A0, B0, C0}, {A1, B1, C1}} = {At(I), At(I + 1)},
                          {PX0, PX1, PY0, PY1, PZ0, PZ1} =
                              box({{min(A0, A1) - Pad, min(B0, B1) - Pad, min(C0, C1) - Pad},
                                   {max(A0, A1) + Pad, max(B0, B1) + Pad, max(C0, C1) + Pad}}, S),
                          %% (within the swept box: the cover stays a part of it)
                          {max(PX0, X0), min(PX1, X1), max(PY0, Y0), min(PY1, Y1), max(PZ0, Z0), min(PZ1, Z1)}
                      end || I <- lists:seq(0, K - 1)],
            Count = lists:foldl(fun(B, N) -> N + box_size(B) end, 0, Pieces),
            Count =< ?MAX_SWEPT_CELLS orelse too_many(R, Move, S),
            lists:usort(lists:append([box_cells(B) || B <- Pieces]))
    end.

%% How far beyond a piece of a move its box reaches: the radius, and far
%% above the rounding of the points that cut the move (Far and Move are the
%% largest coordinate of the start and of the move).
pad(Far, Move, R) -> R + 1.0e-12 * (Far + Move + R).

%% A sweep that would list more cells than the cap: validation
%% (rw_scene_limits) keeps every body's speed below what reaches it, so
%% only a run whose physics gains energy gets here.
-spec too_many(float(), float(), float()) -> no_return().
too_many(R, Move, S) ->
    error({too_many_cells,
           lists:flatten(io_lib:format("a sphere of radius ~s m moving ~s m along an axis in one substep sweeps "
                                       "more than ~b cells of ~s m, the most a sweep may list: it moves faster "
                                       "than its scene's energy allowed at validation",
                                       [short(R), short(Move), ?MAX_SWEPT_CELLS, short(S)]))}).

short(X) -> float_to_list(X, [short]).

%% The most cells swept_cells/4 lists for one sphere and substep; a sweep
%% past it raises error({too_many_cells, Message}).
-spec max_swept_cells() -> pos_integer().
max_swept_cells() -> ?MAX_SWEPT_CELLS.

%% An upper bound on the cells swept_cells/4 lists (before it drops those
%% listed twice) for a sphere of radius R whose centre starts at most Far
%% from the origin along every axis and moves at most Move along each, in
%% cells of side S: the pieces, each at most a step (a cell or a diameter)
%% long, times the cells of a piece's box, per axis at most its length
%% over S plus two, and one more for the rounding of coordinates far out.
-spec sweep_bound(float(), float(), float(), float()) -> float().
sweep_bound(Move, R, S, Far) ->
    Step = max(S, 2.0 * R),
    PerAxis = (Step + 2.0 * pad(Far, Move, R)) / S + 2.0 + 1.0e-15 * (Far + Move) / S,
    (Move / Step + 1.0) * PerAxis * PerAxis * PerAxis.

-spec box(rw_shape:aabb(), float()) -> box().
box({{X0, Y0, Z0}, {X1, Y1, Z1}}, S) ->
    {idx(X0, S), idx(X1, S), idx(Y0, S), idx(Y1, S), idx(Z0, S), idx(Z1, S)}.

-spec box_cells(box()) -> [cell()].
box_cells({X0, X1, Y0, Y1, Z0, Z1}) ->
    [{X, Y, Z} || X <- lists:seq(X0, X1), Y <- lists:seq(Y0, Y1), Z <- lists:seq(Z0, Z1)].

%% How many cells the box holds.
-spec box_size(box()) -> pos_integer().
box_size({X0, X1, Y0, Y1, Z0, Z1}) -> (X1 - X0 + 1) * (Y1 - Y0 + 1) * (Z1 - Z0 + 1).

-spec cell_of(rw_vec:vec(), float()) -> cell().
cell_of({X, Y, Z}, S) -> {idx(X, S), idx(Y, S), idx(Z, S)}.

%% Bucket index in 0..N-1. Blocks of 16x16x16 neighbouring cells share a
%% bucket, so that a body's few cells usually live in one bucket (a call
%% per step; a write over two buckets costs two calls and two casts) while
%% distant regions spread over the pool. Smaller blocks put a larger share
%% of the writes on a block boundary, over two buckets: with 8x8x8, the
%% gas of 20,000 spheres (18 cells across) wrote over three boundary
%% planes per axis instead of one and ran a tenth slower.
-spec bucket(cell(), pos_integer()) -> non_neg_integer().
bucket({X, Y, Z}, N) -> erlang:phash2({X bsr 4, Y bsr 4, Z bsr 4}, N).

idx(X, S) -> floor(X / S).

%% The region in which an AABB keeps Box (see region()): comparing corners
%% with it is much cheaper than hashing them again, and a box near a cell
%% border falls outside it and is hashed exactly.
-spec region(box(), float()) -> region().
region({X0, X1, Y0, Y1, Z0, Z1}, S) ->
    {Ax, Bx} = within(X0, S), {Cx, Dx} = within(X1, S),
    {Ay, By} = within(Y0, S), {Cy, Dy} = within(Y1, S),
    {Az, Bz} = within(Z0, S), {Cz, Dz} = within(Z1, S),
    {Ax, Bx, Cx, Dx, Ay, By, Cy, Dy, Az, Bz, Cz, Dz}.

%% Float division is monotonic, so if the ends map to cell I, every value
%% between them does. Start from the exact borders (grid scenes put spheres
%% right on them) and step inside when rounding puts them in a neighbour.
within(I, S) ->
    M = 1.0e-12 * (abs(I) + 1),
    Lo = first_in(I, S, [I * S, (I + M) * S]),
    Hi = first_in(I, S, [(I + 1 - M) * S]),
    case {Lo, Hi} of
        {none, _} -> {1.0, -1.0};               % empty: always hash again
        {_, none} -> {1.0, -1.0};
        _ -> {Lo, Hi}
    end.

first_in(_I, _S, []) -> none;
first_in(I, S, [V | Rest]) ->
    case idx(V, S) =:= I of
        true -> float(V);
        false -> first_in(I, S, Rest)
    end.

%% A region no box is in: every box is hashed.
-spec no_region() -> region().
no_region() -> {1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0}.

-spec in_region(rw_shape:aabb(), region()) -> boolean().
in_region({{X0, Y0, Z0}, {X1, Y1, Z1}}, {Ax, Bx, Cx, Dx, Ay, By, Cy, Dy, Az, Bz, Cz, Dz}) ->
    X0 >= Ax andalso X0 =< Bx andalso X1 >= Cx andalso X1 =< Dx andalso
        Y0 >= Ay andalso Y0 =< By andalso Y1 >= Cy andalso Y1 =< Dy andalso
        Z0 >= Az andalso Z0 =< Bz andalso Z1 >= Cz andalso Z1 =< Dz.
