%% Volumetric hashing: which integer cells of Z^3 a box touches, and which
%% bucket of a pool owns a cell. Cells are unbounded (bignums far away).
-module(rw_hash).
-export([cells/2, cell_of/2, bucket/2, box/2, box_cells/1]).
-export_type([cell/0, box/0]).

-type cell() :: {integer(), integer(), integer()}.
%% The integer ranges of cells an AABB touches: {X0, X1, Y0, Y1, Z0, Z1}.
-type box() :: {integer(), integer(), integer(), integer(), integer(), integer()}.

%% Every cell of side CellSize that the box touches, in lexicographic
%% order (the order in which the TVHT locks them, Lemma 1).
-spec cells(rw_shape:aabb(), float()) -> [cell()].
cells(AABB, S) -> box_cells(box(AABB, S)).

-spec box(rw_shape:aabb(), float()) -> box().
box({{X0, Y0, Z0}, {X1, Y1, Z1}}, S) ->
    {idx(X0, S), idx(X1, S), idx(Y0, S), idx(Y1, S), idx(Z0, S), idx(Z1, S)}.

-spec box_cells(box()) -> [cell()].
box_cells({X0, X1, Y0, Y1, Z0, Z1}) ->
    [{X, Y, Z} || X <- lists:seq(X0, X1), Y <- lists:seq(Y0, Y1), Z <- lists:seq(Z0, Z1)].

-spec cell_of(rw_vec:vec(), float()) -> cell().
cell_of({X, Y, Z}, S) -> {idx(X, S), idx(Y, S), idx(Z, S)}.

%% Bucket index in 0..N-1. Blocks of 4x4x4 neighbouring cells share a
%% bucket, so that a body's few cells usually live in one or two buckets
%% (one message each per step) while distant regions spread over the pool.
-spec bucket(cell(), pos_integer()) -> non_neg_integer().
bucket({X, Y, Z}, N) -> erlang:phash2({X bsr 2, Y bsr 2, Z bsr 2}, N).

idx(X, S) -> floor(X / S).
