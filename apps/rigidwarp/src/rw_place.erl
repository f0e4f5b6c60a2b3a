%% Placement of one simulation over several nodes (pure): space is cut
%% into slabs along one axis, one slab per node, and a node holds the
%% bodies whose positions lie in its slab and the buckets of the cells
%% there. A body writes to the TVHT cells around it, and meets the bodies
%% near it, so most writes, events and acknowledgements stay on one node.
%%
%% The slabs are cut through the bodies' positions at the start of an
%% incarnation (the scene's start or a checkpoint): along the axis over
%% which the bodies spread the most, at the cell boundaries nearest to
%% equal shares of the bodies. Within a site a cell's bucket is its
%% block's (rw_hash:bucket/2). Which bucket holds a cell
%% never changes a result, only which process computes a contact.
-module(rw_place).
-export([new/4, site_of/2, bucket/2, buckets/1, sites/1, split/2]).
-export_type([placement/0]).

%% Sites 0..K-1; Axis 1..3; Cuts: K-1 ascending cell coordinates along
%% the axis (a cell C belongs to the first site whose cut is above C, else
%% to the last); Per: buckets
%% per site (site S holds buckets S * Per .. S * Per + Per - 1).
-record(place, {sites :: pos_integer(), axis :: 1..3, cuts :: tuple(), per :: pos_integer(), cell :: float()}).
-opaque placement() :: #place{}.

%% A placement of bodies at Positions over Sites nodes with Per buckets
%% each, for cells of edge Cell.
-spec new([rw_vec:vec()], pos_integer(), pos_integer(), float()) -> placement().
new(Positions, Sites, Per, Cell) ->
    Axis = widest(Positions),
    Cells = lists:sort([cell(element(Axis, P), Cell) || P <- Positions]),
    #place{sites = Sites, axis = Axis, cuts = list_to_tuple(cuts(Cells, Sites)), per = Per, cell = Cell}.

%% The site of a position.
-spec site_of(rw_vec:vec(), placement()) -> non_neg_integer().
site_of(P, #place{axis = Axis, cuts = Cuts, cell = Cell}) -> site(cell(element(Axis, P), Cell), Cuts).

%% The bucket of a cell: its block's in the pool of the site it lies in.
-spec bucket(rw_hash:cell(), placement()) -> non_neg_integer().
bucket(Cell, #place{axis = Axis, cuts = Cuts, per = Per}) ->
    Site = site(element(Axis, Cell), Cuts),
    Site * Per + rw_hash:bucket(Cell, Per).

%% How many buckets in all.
-spec buckets(placement()) -> pos_integer().
buckets(#place{sites = K, per = Per}) -> K * Per.

-spec sites(placement()) -> pos_integer().
sites(#place{sites = K}) -> K.

%% Items {Key, Position} by site: a list per site, 0 first.
-spec split([{term(), rw_vec:vec()}], placement()) -> [[term()]].
split(Items, #place{sites = K} = Place) ->
    BySite = lists:foldl(fun({Key, P}, Acc) -> maps:update_with(site_of(P, Place), fun(L) -> [Key | L] end, [Key], Acc) end,
                         #{}, Items),
    [lists:reverse(maps:get(S, BySite, [])) || S <- lists:seq(0, K - 1)].

%%% Internals

%% As rw_hash:cell_of/2 along one axis.
cell(X, Cell) -> floor(X / Cell).

site(B, Cuts) -> site(B, Cuts, 1, tuple_size(Cuts)).

site(_B, _Cuts, I, N) when I > N -> N;
site(B, Cuts, I, N) ->
    case B < element(I, Cuts) of
        true -> I - 1;
        false -> site(B, Cuts, I + 1, N)
    end.

%% The axis of the widest spread of the positions (x on a tie, or none).
widest([]) -> 1;
widest([{X, Y, Z} | Rest]) ->
    {Lo, Hi} = lists:foldl(fun({A, B, C}, {{A0, B0, C0}, {A1, B1, C1}}) ->
                                   {{min(A, A0), min(B, B0), min(C, C0)}, {max(A, A1), max(B, B1), max(C, C1)}}
                           end, {{X, Y, Z}, {X, Y, Z}}, Rest),
    Spread = [element(I, Hi) - element(I, Lo) || I <- [1, 2, 3]],
    {_, Axis} = lists:max([{S, -I} || {S, I} <- lists:zip(Spread, [1, 2, 3])]),
    -Axis.

%% K-1 cuts through sorted cell coordinates, each halfway between the cells
%% of the last body of one equal share and the first of the next (a body's
%% writes reach the cells next to its own: a cut in the gap between two
%% groups of bodies keeps each group's writes on its node), never cutting a
%% cell, and each above the one before: with few distinct cells, later
%% sites may hold no body at all.
cuts(_Cells, 1) -> [];
cuts([], K) -> lists:seq(1, K - 1);
cuts(Cells, K) ->
    N = length(Cells),
    Sorted = list_to_tuple(Cells),
    {Cuts, _} = lists:mapfoldl(fun(I, Prev) ->
                                       Next = min(N, 1 + (I * N) div K),
                                       Last = element(max(1, Next - 1), Sorted),
                                       C = max(Prev + 1, (Last + element(Next, Sorted) + 1) bsr 1),
                                       {C, C}
                               end, element(1, Sorted), lists:seq(1, K - 1)),
    Cuts.
