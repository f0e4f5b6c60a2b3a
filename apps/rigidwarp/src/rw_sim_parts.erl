%% The parts that the tree of a simulation on one node (rw_sim_sup) and
%% the tree of one node's site of a simulation over several (rw_site) are
%% built of: supervisors of no restarts (a process of a simulation shares
%% state no other can rebuild: the run restarts the whole simulation), the
%% pool of buckets, the bodies' supervisor, child specs.
-module(rw_sim_parts).
-behaviour(supervisor).
-include("rigidwarp.hrl").
-export([worker/3, bucket_pool/7, body_pool/0, start_bodies/3, stop/1, init/1]).

%% Start a body for each {Sphere, State}: [{Idx, Id, Pid}].
-spec start_bodies(pid(), #sim{}, [{#sphere{}, #st{}}]) -> [{non_neg_integer(), binary(), pid()}].
start_bodies(BodySup, Sim, Bodies) ->
    Started = [begin
                   {ok, Pid} = supervisor:start_child(BodySup, [Sim, Sphere, St]),
                   {Idx, Id, Pid}
               end || {#sphere{idx = Idx, id = Id} = Sphere, St} <- Bodies],
    true = ets:insert(Sim#sim.procs, [{Idx, Pid} || {Idx, _, Pid} <- Started]),
    Started.

%% Stop a simulation's supervisor and wait until it is gone (killed if it
%% takes more than 5 s). A monitor, not a link: the supervisor may be gone
%% already, its exit taken (a monitor of a dead process is told at once).
-spec stop(pid()) -> ok.
stop(Sup) ->
    MRef = erlang:monitor(process, Sup),
    exit(Sup, shutdown),
    receive {'DOWN', MRef, process, Sup, _} -> ok
    after 5000 ->
            exit(Sup, kill),
            receive {'DOWN', MRef, process, Sup, _} -> ok end
    end.

%% The child spec of a pool of N buckets for the cells of Bodies bodies,
%% whose work is recorded into Trace (rw_trace) when the simulation is
%% traced, keeping their segments in C where Native and the library is
%% loaded here. As the pool starts, before the buckets' heaps (the largest) are
%% touched, a large simulation asks for huge pages
%% (rw_native:huge_pages_for/1).
-spec bucket_pool(#model{}, pos_integer(), pos_integer(), rw_stats:counters() | undefined, ets:tid() | undefined,
                  non_neg_integer(), boolean()) -> supervisor:child_spec().
bucket_pool(M, Dt, N, Profile, Trace, Bodies, Native) ->
    #{id => buckets, type => supervisor, restart => permanent,
      start => {supervisor, start_link, [?MODULE, {buckets, M, Dt, N, Profile, Trace, Bodies, Native}]}}.

%% The pool decides once where its buckets keep their segments (rw_cells:
%% in C where the library is loaded) and sizes their heaps for it. A
%% bucket whose segments are in the Erlang heap keeps those of every body writing in its cells since GVT, and a
%% heap sized to what survived its last collection copies them again and
%% again: its heap never shrinks below 3200 words per body it holds on
%% average, at most 1M words (8 MiB). (20,000 spheres ran 10-15 % faster
%% with 1M words than with the default 233; 500 the same.) With the
%% segments in C its heap holds only the requests in hand: 8192 words,
%% whose collections stay in the caches.
bucket_heap(native, _Bodies, _Buckets) -> 8192;
bucket_heap(erlang, Bodies, Buckets) -> max(233, min(1 bsl 20, 3200 * Bodies div Buckets)).

%% The child spec of the bodies' supervisor.
-spec body_pool() -> supervisor:child_spec().
body_pool() ->
    #{id => bodies, type => supervisor, restart => permanent, start => {supervisor, start_link, [?MODULE, bodies]}}.

%% The child spec of a worker.
-spec worker(atom(), module(), [term()]) -> supervisor:child_spec().
worker(Id, Mod, Args) ->
    #{id => Id, start => {Mod, start_link, Args}, restart => permanent, shutdown => 1000, type => worker}.

-spec init(sim | {buckets, #model{}, pos_integer(), pos_integer(), rw_stats:counters() | undefined,
                  ets:tid() | undefined, non_neg_integer(), boolean()} | bodies) ->
          {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init(sim) ->
    {ok, {#{strategy => rest_for_one, intensity => 0, period => 1}, []}};
init({buckets, M, Dt, N, Profile, Trace, Bodies, Native}) ->
    ok = rw_native:huge_pages_for(Bodies),
    Store = case Native andalso rw_native:loaded() of
                true -> native;
                false -> erlang
            end,
    Heap = bucket_heap(Store, Bodies, N),
    {ok, {#{strategy => one_for_all, intensity => 0, period => 1},
          [#{id => {bucket, I}, start => {rw_bucket, start_link, [M, Dt, Store, Profile, Trace, Heap]},
             restart => permanent, shutdown => 1000} || I <- lists:seq(0, N - 1)]}};
init(bodies) ->
    {ok, {#{strategy => simple_one_for_one, intensity => 0, period => 1},
          [#{id => body, start => {rw_body, start_link, []}, restart => temporary, shutdown => 1000}]}}.
