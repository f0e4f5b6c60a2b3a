%% The engine's hot loops in C (c_src/, one file per concern, built into
%% priv/rw_native.so; its function table in c_src/rw_native.c): a body's
%% free flight and a contact group's island, the substeps of rw_chain; the
%% scan of two bodies' packed positions for their first touch and the
%% measure of a group's states, in rw_states; a bucket's cells, rw_cells.
%% Each does the Erlang code's float operations in the same order, so the
%% results are bit for bit the same; where the Erlang code would raise or
%% fail on its arguments, the C code answers fallback (or stops short) and
%% the caller runs the Erlang code from the same point. Where the library
%% cannot be loaded (the escript copied away from its build) enabled/0 says
%% so, the callers run the Erlang code alone, slower and with the same
%% results.
%%
%% The switch is per process: a run tells each of its processes (bodies,
%% buckets) whether to use the C loops (its option native, by default the
%% application's environment native), so that runs with either setting may
%% go on side by side in one VM, and a node without the library runs the
%% Erlang code whatever the run asks for.
-module(rw_native).
-include_lib("rw_physics/include/rw_physics.hrl").
-export([free_run/13, first_touch/10, island_run/10, measure/2, huge_pages/0, huge_pages_for/1, loaded/0, enabled/0,
         use/1, default/0, in_use/2, library/0, library_variable/0]).
-export([c_layouts/0, erlang_layouts/0, check_layouts/2]).
-export([cells_new/0, cells_store/5, cells_probe/4, cells_delete/4, cells_gc/2, cells_dump/1]).
-export_type([cells/0, layout/0]).

%% A record as the C code reads it ({Name, TupleSize, [{Field,
%% Position}]}) or as the Erlang code was compiled with it ({Name,
%% TupleSize, Fields in order}).
-type layout() :: {atom(), pos_integer(), [{atom(), pos_integer()}] | [atom()]}.

%% A TVHT bucket's segments kept in C (c_src/rw_cells.c): rw_cells' map of
%% cells, writers and segments outside the Erlang heap. Changed in place
%% by its calls, so only its bucket may use it.
-opaque cells() :: reference().
-on_load(init/0).

%% (a call's time counted in a traced task: rw_trace)
-define(TIMED(Call), case rw_trace:timing() of
                         false -> Call;
                         true -> ok = rw_trace:native_begin(), rw_trace:native_end(Call)
                     end).

%% the library's file, or none
-define(LIBRARY, {?MODULE, library}).
%% (process dictionary) whether this process uses the C loops
-define(IN_PROCESS, '$rw_native').

%% The library from the application's priv directory (rw_priv: the
%% escript's too) or, on a node a run has loaded the engine on (rw_nodes),
%% from where the run has copied it; unused (one warning) where it reads
%% the records otherwise than this code was compiled with them.
init() ->
    Library = case load_first(candidates()) of
                  none -> none;
                  File ->
                      case check_layouts(c_layouts(), erlang_layouts()) of
                          ok -> File;
                          {error, Why} ->
                              logger:warning("rigidwarp: the C loops' library ~ts is not used, the Erlang code runs: ~ts",
                                             [File, Why]),
                              none
                      end
              end,
    persistent_term:put(?LIBRARY, Library).

%% Where the loaded library reads the records.
-spec c_layouts() -> [layout()].
c_layouts() -> nif_layouts().

nif_layouts() -> erlang:nif_error(not_loaded).

%% The records as this code was compiled with them.
-spec erlang_layouts() -> [layout()].
erlang_layouts() ->
    [{model, record_info(size, model), record_info(fields, model)},
     {sphere, record_info(size, sphere), record_info(fields, sphere)},
     {st, record_info(size, st), record_info(fields, st)},
     {fixture, record_info(size, fixture), record_info(fields, fixture)}].

%% Does the C code (Assumed) read every record where Actual has it?
-spec check_layouts([layout()], [layout()]) -> ok | {error, string()}.
check_layouts(Assumed, Actual) ->
    Wrong = [Why || {Record, Size, Fields} <- Assumed, Why <- [layout_error(Record, Size, Fields, Actual)],
                    Why =/= ok],
    case Wrong of
        [] -> ok;
        [Why | _] -> {error, Why}
    end.

layout_error(Record, Size, Fields, Actual) ->
    case lists:keyfind(Record, 1, Actual) of
        false ->
            format("the C code reads a record #~s{} the Erlang code does not have", [Record]);
        {_, Size, Names} when length(Names) =:= Size - 1 ->
            case [{F, P} || {F, P} <- Fields, not (P >= 1 andalso P < Size andalso lists:nth(P, Names) =:= F)] of
                [] -> ok;
                [{F, P} | _] -> format("the C code reads #~s.~s at position ~b, the Erlang record has ~0p", [Record, F, P, Names])
            end;
        {_, ActualSize, _} ->
            format("the C code reads #~s{} as a tuple of ~b elements, the Erlang record has ~b", [Record, Size, ActualSize])
    end.

format(Format, Args) -> lists:flatten(io_lib:format(Format, Args)).

load_first([]) -> none;
load_first([Dir | Rest]) ->
    File = filename:join(Dir, "rw_native"),
    case erlang:load_nif(File, 0) of
        ok -> File ++ ".so";
        {error, _} -> load_first(Rest)
    end.

candidates() ->
    Copied = case os:getenv(library_variable()) of
                 false -> [];
                 Dir -> [Dir]
             end,
    %% (outside an escript and without the application's priv directory,
    %% rw_priv finds none)
    Priv = try [rw_priv:dir()]
           catch _:_ -> []
           end,
    Copied ++ Priv.

%% The environment variable naming the directory of a copy of the library
%% (set by rw_nodes on a node while it loads the engine there).
-spec library_variable() -> string().
library_variable() -> "RIGIDWARP_NATIVE_DIR".

%% The library loaded here, to copy to another node, or none.
-spec library() -> {ok, binary()} | none.
library() ->
    case persistent_term:get(?LIBRARY, none) of
        none -> none;
        File ->
            case file:read_file(File) of
                {ok, Lib} -> {ok, Lib};
                {error, _} -> none
            end
    end.

%% Is the C library loaded?
-spec loaded() -> boolean().
loaded() -> persistent_term:get(?LIBRARY, none) =/= none.

%% Does this process use the C loops? Where it was not told (use/1), it
%% does where the library is loaded. (Callers ask once per loop they run,
%% and call them only then.)
-spec enabled() -> boolean().
enabled() ->
    case get(?IN_PROCESS) of
        undefined -> loaded();
        Native -> Native
    end.

%% This process uses the C loops (true: where the library is loaded) or
%% the Erlang code alone (false). A run's processes are told its setting
%% as they start; tests compare the two, bit for bit.
-spec use(boolean()) -> ok.
use(Native) when is_boolean(Native) ->
    _ = put(?IN_PROCESS, Native andalso loaded()),
    ok.

%% Whether a run uses the C loops unless told otherwise: the application's
%% environment native (true where it is not a boolean).
-spec default() -> boolean().
default() ->
    case application:get_env(rigidwarp, native, true) of
        Native when is_boolean(Native) -> Native;
        Bad ->
            logger:warning("rigidwarp: native must be true or false, got ~0p; the C loops are used", [Bad]),
            true
    end.

%% Whether a run that asks for the C loops (Native) runs them on every one
%% of Nodes: each runs them where its library is loaded.
-spec in_use(boolean(), [node()]) -> boolean().
in_use(Native, Nodes) ->
    Native andalso lists:all(fun(Node) when Node =:= node() -> loaded();
                                (Node) -> try erpc:call(Node, ?MODULE, loaded, [], 5000) =:= true
                                          catch _:_ -> false
                                          end
                             end, Nodes).

%% Ask Linux to back the VM's super carrier (+MMscs, as the escript, the
%% benchmarks and `make shell` start the VM) with transparent huge pages,
%% where the system leaves that to the program (its setting "madvise").
%% Tens of thousands of bodies keep gigabytes of heaps, segments and records
%% in use at once, and with 4 KiB pages nearly every step misses the TLB:
%% 20,000 spheres ran 11-30 % faster backed by 2 MiB pages (doc/performance.md).
%% Answers the bytes advised: 0 without a super carrier or off Linux.
-spec huge_pages() -> non_neg_integer() | {error, integer()}.
huge_pages() -> nif_huge_pages().

%% As a simulation of N bodies starts its TVHT on this node: huge pages
%% from 5000 bodies on, unless the application's environment says {huge_pages,
%% false}. A small scene gains little, and its short runs pay for the
%% kernel's zeroing of whole 2 MiB pages at their first touch (a third of a
%% slow run of Parallel 500, whose runs took 0.2 or 0.5 s by that alone).
%% Once advised, the carrier stays so for the VM's life.
-define(HUGE_PAGES_BODIES, 5000).
-spec huge_pages_for(non_neg_integer()) -> ok.
huge_pages_for(N) ->
    _ = N >= ?HUGE_PAGES_BODIES andalso loaded() andalso application:get_env(rigidwarp, huge_pages, true) =:= true
        andalso huge_pages(),
    ok.

nif_huge_pages() -> erlang:nif_error(not_loaded).

%% A body alone without CCD flying free from T (rw_chain:flight/26): while
%% T < Last, T is neither Sync nor Busy (none: no such substep) and the
%% body is in Zone (always, or {AX, AY, AZ, L2}: within sqrt(L2) of the
%% anchor), substeps of Dt seconds (DtT ticks) under Gravity (undefined or
%% a vector) with Integrator. State is {X, Y, Z, VX, VY, VZ}, Q and W the
%% orientation and spin (undefined without rotation), Acc {First, Box,
%% Reach} as rw_chain measures the states. Returns the time and state
%% reached, the orientation, the states' records to append and Acc, or
%% fallback (nothing done: the Erlang code takes over).
-spec free_run(non_neg_integer(), non_neg_integer(), pos_integer(), float(), non_neg_integer() | none,
               non_neg_integer() | none, always | {float(), float(), float(), float()},
               undefined | rw_vec:vec(), atom(), {float(), float(), float(), float(), float(), float()},
               undefined | rw_quat:quat(), undefined | rw_vec:vec(),
               {none | some, rw_shape:box6(), float()}) ->
          {non_neg_integer(), {float(), float(), float(), float(), float(), float()}, undefined | rw_quat:quat(),
           binary(), {none | some, rw_shape:box6(), float()}} | fallback.
free_run(T, Last, DtT, Dt, Sync, Busy, Zone, Gravity, Integrator, State, Q, W, Acc) ->
    ?TIMED(nif_free_run(T, Last, DtT, Dt, Sync, Busy, Zone, Gravity, Integrator, State, Q, W, Acc)).

nif_free_run(_T, _Last, _DtT, _Dt, _Sync, _Busy, _Zone, _Gravity, _Integrator, _State, _Q, _W, _Acc) ->
    erlang:nif_error(not_loaded).

%% rw_states:touch/10 over the packed records BinA (SizeA bytes each,
%% from the IA-th) and BinB: the first offset K in 0..Left at which the
%% positions are closer than Sum, none, or fallback.
-spec first_touch(binary(), pos_integer(), pos_integer(), binary(), pos_integer(), pos_integer(),
                  non_neg_integer(), float(), float(), float() | undefined) -> non_neg_integer() | none | fallback.
first_touch(BinA, SizeA, IA, BinB, SizeB, IB, Left, Sum, Margin, Reach) ->
    ?TIMED(nif_first_touch(BinA, SizeA, IA, BinB, SizeB, IB, Left, Sum, Margin, Reach)).

nif_first_touch(_BinA, _SizeA, _IA, _BinB, _SizeB, _IB, _Left, _Sum, _Margin, _Reach) ->
    erlang:nif_error(not_loaded).

%% A contact group's substeps (rw_island:step/3 without CCD) from T while
%% T < Stop, not at the group's start: Model, the members' Spheres
%% (ascending idx), the scene's Fixtures, the members' States at T, Acc
%% (none or, for a body alone in rw_chain:flight/26, {First, Box, Reach}
%% as free_run/13 takes it), the sync points from T on (ascending) and the
%% known contacts with bodies outside from T on, {Time, MemberIdx,
%% PartnerIdx, Effect} ascending by time. Returns the time and states
%% reached, per member the states after T up to there (rw_states' layout),
%% Acc measured over them and the sync points passed (as rw_chain:passed()
%% and in ascending order), or fallback. It may stop short of Stop (at
%% most some thousand member-substeps a call, or before a substep where the
%% Erlang code would raise).
-spec island_run(non_neg_integer(), non_neg_integer(), pos_integer(), tuple(), tuple(), list(), tuple(),
                 none | {none | some, rw_shape:box6(), float()}, [non_neg_integer()],
                 [{non_neg_integer(), non_neg_integer(), non_neg_integer(), rw_response:effect()}]) ->
          {non_neg_integer(), tuple(), [binary()], none | {none | some, rw_shape:box6(), float()},
           [{non_neg_integer(), tuple(), tuple()}]} | fallback.
island_run(T, Stop, DtT, Model, Spheres, Fixtures, States, Acc, Syncs, Outside) ->
    ?TIMED(nif_island_run(T, Stop, DtT, Model, Spheres, Fixtures, States, Acc, Syncs, Outside)).

nif_island_run(_T, _Stop, _DtT, _Model, _Spheres, _Fixtures, _States, _Acc, _Syncs, _Outside) ->
    erlang:nif_error(not_loaded).

%% rw_states:seal/3's measurement of the positions of the states in Bin
%% (Size bytes each): their box and reach (undefined where a step between
%% them overflows), or fallback.
-spec measure(binary(), pos_integer()) -> {rw_shape:box6(), float() | undefined} | fallback.
measure(Bin, Size) ->
    ?TIMED(nif_measure(Bin, Size)).

nif_measure(_Bin, _Size) ->
    erlang:nif_error(not_loaded).

%% An empty set of cells, for rw_cells when the library is loaded.
-spec cells_new() -> cells().
cells_new() -> nif_cells_new().

%% rw_cells:store/7's segments: Owner's Write in the cells of Spans, each
%% from its Ta =< UpTo on and cut at UpTo.
-spec cells_store(cells(), term(), rw_cells:write(), [rw_cells:span()], non_neg_integer()) -> ok.
cells_store(Store, Owner, Write, Spans, UpTo) ->
    ?TIMED(nif_cells_store(Store, Owner, Write, Spans, UpTo)).

%% rw_cells:probe/3's windows: the member pairs of Write and of other
%% writers' segments in the cells of Spans whose times meet, whose writes'
%% boxes and whose own boxes overlap, each with the window in which they
%% meet and the other member's payload (a pair's windows on different
%% writes of the other member apart, in no order). With Dt > 0 (no CCD)
%% each window is scanned as rw_states:first_touch/6 would, and only the
%% windows of the earliest touches come back, each narrowed to its substep,
%% with any the scan left to the Erlang code that begin no later.
-spec cells_probe(cells(), rw_cells:write(), [rw_cells:span()], non_neg_integer()) ->
          [{MyIdx :: non_neg_integer(), OtherIdx :: non_neg_integer(), Lo :: non_neg_integer(),
            Hi :: non_neg_integer(), rw_cells:payload()}].
cells_probe(Store, Write, Spans, Dt) ->
    ?TIMED(nif_cells_probe(Store, Write, Spans, Dt)).

%% Owner's segments in Cells end at R at the latest.
-spec cells_delete(cells(), term(), non_neg_integer(), [rw_hash:cell()]) -> ok.
cells_delete(Store, Owner, R, Cells) ->
    ?TIMED(nif_cells_delete(Store, Owner, R, Cells)).

%% Each writer keeps the segments of its own that end at Gvt or later. (A
%% large store is swept in slices, each a call of at most about half a
%% time slice, each going on where the one before stopped; the writes left
%% without segments are freed on a dirty scheduler.)
-spec cells_gc(cells(), non_neg_integer()) -> ok.
cells_gc(Store, Gvt) -> cells_gc(Store, Gvt, 0).

cells_gc(Store, Gvt, From) ->
    case ?TIMED(nif_cells_gc(Store, Gvt, From)) of
        ok -> ok;
        free -> ?TIMED(nif_cells_free(Store));
        Next -> cells_gc(Store, Gvt, Next)
    end.

%% All segments, per cell and writer, newest first: {Cell, Owner, [{Ta,
%% Tb, write's box, write's T0, member spans}]} (a box with a corner past
%% 64 bits reads as all of space).
-spec cells_dump(cells()) ->
          [{rw_hash:cell(), term(), [{non_neg_integer(), non_neg_integer(), rw_cells:bounds(), non_neg_integer(),
                                       [rw_cells:member_span()]}]}].
cells_dump(Store) -> nif_cells_dump(Store).

nif_cells_new() -> erlang:nif_error(not_loaded).
nif_cells_store(_Store, _Owner, _Write, _Spans, _UpTo) -> erlang:nif_error(not_loaded).
nif_cells_probe(_Store, _Write, _Spans, _Dt) -> erlang:nif_error(not_loaded).
nif_cells_delete(_Store, _Owner, _R, _Cells) -> erlang:nif_error(not_loaded).
nif_cells_gc(_Store, _Gvt, _From) -> erlang:nif_error(not_loaded).
nif_cells_free(_Store) -> erlang:nif_error(not_loaded).
nif_cells_dump(_Store) -> erlang:nif_error(not_loaded).
