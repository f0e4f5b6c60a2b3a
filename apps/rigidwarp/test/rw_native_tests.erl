%% The C loops (rw_native) against the Erlang code they stand for: the same
%% results bit for bit, with the library used and with the Erlang code alone,
%% at awkward doubles too (signed zeros, subnormals, coordinates near the
%% largest double, where the Erlang code raises badarith and the C code
%% must hand over to it). rw_chain_tests and rw_states_tests run their cases
%% both ways as well.
-module(rw_native_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").

%% The build compiles the library, and the tests run against it: else the
%% comparisons below would compare the Erlang code with itself.
loaded_test() ->
    ?assert(rw_native:loaded()).

%% The library reads #model{}, #sphere{}, #st{} and #fixture{} where the
%% Erlang code has their fields; a record with a field more, two fields
%% swapped, another size or missing is refused, naming the record.
record_layouts_test() ->
    C = rw_native:c_layouts(),
    Erlang = rw_native:erlang_layouts(),
    ?assertEqual([fixture, model, sphere, st], lists:sort([R || {R, _, _} <- C])),
    ?assertEqual(ok, rw_native:check_layouts(C, Erlang)),
    {model, Size, [Dt | Rest]} = lists:keyfind(model, 1, Erlang),
    Refused = fun(Model) ->
                      {error, Why} = rw_native:check_layouts(C, lists:keystore(model, 1, Erlang, Model)),
                      ?assertNotEqual(nomatch, string:find(Why, "#model"))
              end,
    Refused({model, Size + 1, [Dt, added | Rest]}),
    Refused({model, Size + 1, Rest ++ [Dt, added]}),
    Refused({model, Size, [hd(Rest), Dt | tl(Rest)]}),
    Refused({model, Size - 1, Rest}),
    {error, Missing} = rw_native:check_layouts(C, lists:keydelete(st, 1, Erlang)),
    ?assertNotEqual(nomatch, string:find(Missing, "#st")).

%% A body alone in free flight, no fixture, at awkward positions, velocities
%% and spins, with every integrator, across sync points and a known
%% contact: rw_chain:run/5's states, sync points and island, or its
%% exception, the same both ways.
free_flight_at_awkward_doubles_test() ->
    _ = rand:seed(exsss, {5, 6, 7}),
    Results = [rw_test_lib:both_ways(fun() -> run(Case) end) || K <- lists:seq(1, 600), Case <- [free_case(K)]],
    [?assert(rw_test_lib:bitwise_equal(Native, Erlang)) || {Native, Erlang} <- Results],
    %% the cases run to their end and, some, into badarith
    Kinds = lists:usort([element(1, Native) || {Native, _} <- Results]),
    ?assertEqual([error, ok], Kinds).

free_case(K) ->
    Rot = K rem 2 =:= 0,
    Gravity = case K rem 5 of
                  0 -> undefined;
                  _ -> rw_test_lib:awkward_vec()
              end,
    Integrator = lists:nth(K rem 3 + 1, [symplectic_euler, explicit_euler, verlet]),
    M = #model{gravity = Gravity, integrator = Integrator, rotation = Rot, dt = lists:nth(K rem 2 + 1, [0.001, 1.0e-6])},
    Sphere = #sphere{idx = 1, id = <<"s">>, radius = 0.5, mass = 1.0, inv_mass = 1.0, inv_inertia = 10.0},
    St = case Rot of
             true ->
                 W = case rand:uniform(3) of
                         1 -> {-0.0, 0.0, -0.0};
                         _ -> rw_test_lib:awkward_vec()
                     end,
                 #st{p = rw_test_lib:awkward_vec(), v = rw_test_lib:awkward_vec(), q = {{0.0, 0.0, 0.0}, 1.0}, w = W};
             false -> #st{p = rw_test_lib:awkward_vec(), v = rw_test_lib:awkward_vec()}
         end,
    T = rand:uniform(50),
    Last = T + rand:uniform(100),
    TL = case rand:uniform(3) of
             1 -> rw_timeline:put_contacts(T + 3, #{{T + 3, 0, 1, make_ref()} => {1, 0, {{0.0, 0.5, 0.0}, undefined, {0.0, 0.0, 0.0}}}},
                                           rw_timeline:new());
             _ -> rw_timeline:new()
         end,
    Cal = rw_sync:new(10, 64, Last, 0),
    {T, St, Last, {M, 1, none, TL, Cal}, rw_island:new(M, [Sphere], [])}.

run({T, St, Last, Ctx, Island}) -> rw_chain:run(T, {St}, Last, Ctx, Island).

%% The scan for the first touch over awkward positions, far apart, at the
%% same place, near overflow, with and without the bodies' reach.
first_touch_at_awkward_doubles_test() ->
    _ = rand:seed(exsss, {8, 9, 10}),
    Results = [rw_test_lib:both_ways(fun() -> first_touch(Case) end)
               || K <- lists:seq(1, 2000), Case <- touch_case() ++ approach_case(K)],
    [?assert(rw_test_lib:bitwise_equal(Native, Erlang)) || {Native, Erlang} <- Results],
    Found = lists:usort([case R of {ok, K} when is_integer(K) -> found; {ok, none} -> none; _ -> raised end
                         || {R, _} <- Results]),
    ?assertEqual([found, none, raised], Found).

%% Two bodies' packed paths (none where building them overflows), scanned
%% from offsets of their own, to the end of the shorter or one past it.
touch_case() ->
    Base = rw_test_lib:awkward_vec(),
    Path = fun(N) ->
                   Step = rw_test_lib:awkward_vec(),
                   Scale = math:pow(10.0, -rand:uniform(300)),
                   [#st{p = rw_vec:madd(Base, Step, float(I) * Scale), v = {0.0, 0.0, 0.0}} || I <- lists:seq(1, N)]
           end,
    NA = rand:uniform(40),
    NB = case rand:uniform(2) of 1 -> NA; 2 -> rand:uniform(40) end,
    try
        A = rw_states:pack(Path(NA), undefined, false, false),
        B = rw_states:pack(Path(NB), undefined, false, false),
        IA = rand:uniform(NA),
        IB = case NA =:= NB andalso rand:uniform(2) =:= 1 of true -> IA; false -> rand:uniform(NB) end,
        Left = min(NA - IA, NB - IB) + case rand:uniform(8) of 1 -> 1; _ -> 0 end,
        [{A, IA, B, IB, Left, lists:nth(rand:uniform(4), [0.0, 1.0e-300, 1.0, abs(rw_test_lib:awkward_double())])}]
    catch
        error:badarith -> []
    end.

%% One body coming at another still one from afar over a long window (up
%% to some thousand substeps, one in fifty cases): the scan skips ahead by
%% the gap over the reach, to the touch or past the window's end.
approach_case(K) when K rem 50 =:= 0 ->
    N = rand:uniform(3000),
    Speed = rand:uniform() * 0.01,
    Start = 1.0 + rand:uniform() * Speed * N * 1.5,
    Still = [#st{p = {-0.0, 0.0, 0.0}, v = {0.0, 0.0, 0.0}} || _ <- lists:seq(1, N)],
    Coming = [#st{p = {Start - float(I) * Speed, 5.0e-324, -0.0}, v = {-Speed, 0.0, 0.0}} || I <- lists:seq(1, N)],
    A = rw_states:pack(Still, undefined, false, false),
    B = rw_states:pack(Coming, undefined, false, false),
    I = rand:uniform(N),
    [{A, I, B, I, N - I, 1.0}];
approach_case(_K) ->
    [].

first_touch({A, IA, B, IB, Left, Sum}) -> rw_states:first_touch(A, IA, B, IB, Left, Sum).

%% A group's states sealed (their box and reach measured) at awkward
%% positions: signed zeros, subnormals, steps that overflow.
seal_at_awkward_doubles_test() ->
    _ = rand:seed(exsss, {11, 12, 13}),
    Results = [rw_test_lib:both_ways(fun() -> rw_states:seal(Bin, Rot, false) end)
               || _ <- lists:seq(1, 500), Rot <- [false, true],
                  Bin <- [<< <<(rw_states:append(<<>>, St, undefined, Rot))/binary>>
                             || St <- [awkward_state(Rot) || _ <- lists:seq(1, rand:uniform(20))] >>]],
    [?assert(rw_test_lib:bitwise_equal(Native, Erlang)) || {Native, Erlang} <- Results],
    Reaches = lists:usort([is_float(rw_states:reach(Sealed)) || {{ok, Sealed}, _} <- Results]),
    ?assertEqual([false, true], Reaches).

awkward_state(false) -> #st{p = rw_test_lib:awkward_vec(), v = rw_test_lib:awkward_vec()};
awkward_state(true) -> #st{p = rw_test_lib:awkward_vec(), v = rw_test_lib:awkward_vec(), q = {rw_test_lib:awkward_vec(), rw_test_lib:awkward_double()}, w = rw_test_lib:awkward_vec()}.

%% A step longer than the C loop takes in one call (4096 substeps) and a
%% scan longer than it takes at all: the same results, over several calls
%% and in Erlang.
long_runs_test() ->
    M = #model{gravity = {0.0, -9.81, 0.0}, dt = 1.0e-5},
    Sphere = #sphere{idx = 1, id = <<"s">>, radius = 0.5, mass = 1.0, inv_mass = 1.0, inv_inertia = 10.0},
    Case = {0, #st{p = {0.0, 100.0, 0.0}, v = {1.0, 2.0, -0.0}}, 10000,
            {M, 1, none, rw_timeline:new(), rw_sync:new(10000, 20000, 10000, 0)}, rw_island:new(M, [Sphere], [])},
    {Native, Erlang} = rw_test_lib:both_ways(fun() -> run(Case) end),
    ?assertMatch({ok, {_, [_], _}}, Native),
    ?assert(rw_test_lib:bitwise_equal(Native, Erlang)),
    {ok, {_, [Packed], _}} = Native,
    ?assertEqual(10000, rw_states:count(Packed)),
    Still = rw_states:pack(lists:duplicate(70001, #st{p = {0.0, 0.0, 0.0}, v = {0.0, 0.0, 0.0}}), undefined, false, false),
    Far = rw_states:pack(lists:duplicate(70001, #st{p = {3.0, 0.0, 0.0}, v = {0.0, 0.0, 0.0}}), undefined, false, false),
    ?assertEqual({{ok, none}, {ok, none}}, rw_test_lib:both_ways(fun() -> rw_states:first_touch(Still, 1, Far, 1, 70000, 1.0) end)),
    %% (at the scan's limit, 65536 substeps, and one past it)
    [?assertEqual({{ok, none}, {ok, none}}, rw_test_lib:both_ways(fun() -> rw_states:first_touch(Still, 1, Far, 1, Left, 1.0) end))
     || Left <- [65535, 65536, 65537]].

%% Arguments the C code does not take are the Erlang code's.
fallback_test() ->
    Acc = {none, {0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, 0.0},
    ?assertEqual(fallback, rw_native:free_run(0, 10, 1, 0.001, none, none, always, undefined, symplectic_euler,
                                              {0, 0.0, 0.0, 0.0, 0.0, 0.0}, undefined, undefined, Acc)),
    ?assertEqual(fallback, rw_native:free_run(0, 10, 1, 0.001, none, none, always, {0.0, -9.81, 0.0}, midpoint,
                                              {0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, undefined, undefined, Acc)),
    Bin = <<0:(48 * 8)>>,
    ?assertEqual(fallback, rw_native:first_touch(Bin, 48, 2, Bin, 48, 1, 0, 1.0, 0.0, undefined)),
    ?assertEqual(0, rw_native:first_touch(Bin, 48, 1, Bin, 48, 1, 0, 1.0, 0.0, undefined)),
    %% a step of no substeps
    ?assertMatch({3, _, undefined, <<>>, Acc},
                 rw_native:free_run(3, 3, 1, 0.001, none, none, always, undefined, symplectic_euler,
                                    {0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, undefined, undefined, Acc)).

%% Offsets and times at the ends of 64 bits: nothing read outside a
%% binary (an offset times a record size wraps past 2^64), no step count
%% that overflows; the Erlang code takes over. (make sanitize runs these
%% under AddressSanitizer and UndefinedBehaviorSanitizer.)
limits_test() ->
    Bin = <<0:(48 * 8)>>,
    [?assertEqual(fallback, rw_native:first_touch(Bin, 48, IA, Bin, 48, 1, 0, 1.0, 0.0, undefined))
     || IA <- [1 bsl 62, (1 bsl 62) + 1, (1 bsl 63) - 1, 0, -1]],
    ?assertEqual(fallback, rw_native:first_touch(Bin, 1 bsl 62, 1, Bin, 48, 1, 0, 1.0, 0.0, undefined)),
    ?assertEqual(fallback, rw_native:first_touch(Bin, 48, 1, Bin, 48, 1 bsl 62, 3, 1.0, 0.0, undefined)),
    Acc = {none, {0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, 0.0},
    Free = fun(T, Last, DtT) ->
                   rw_native:free_run(T, Last, DtT, 0.001, none, none, always, undefined, symplectic_euler,
                                      {0.0, 0.0, 0.0, 1.0, 0.0, 0.0}, undefined, undefined, Acc)
           end,
    Max = (1 bsl 63) - 1,
    [?assertEqual(fallback, Free(T, Last, DtT))
     || {T, Last, DtT} <- [{-(1 bsl 63), Max, 1}, {0, Max, 2}, {1, Max, Max}, {-5, 10, 1}]],
    %% (at most 4096 substeps a call, however far Last is)
    ?assertMatch({4096, _, _, _, _}, Free(0, 1 bsl 62, 1)),
    M = #model{},
    Spheres = {#sphere{idx = 0, id = <<"a">>, radius = 0.1, mass = 1.0, inv_mass = 1.0, inv_inertia = 250.0},
               #sphere{idx = 1, id = <<"b">>, radius = 0.1, mass = 1.0, inv_mass = 1.0, inv_inertia = 250.0}},
    States = {#st{p = {0.0, 0.0, 0.0}, v = {1.0, 0.0, 0.0}}, #st{p = {1.0, 0.0, 0.0}, v = {-1.0, 0.0, 0.0}}},
    Island = fun(T, Stop) -> rw_native:island_run(T, Stop, 1, M, Spheres, [], States, none, [], []) end,
    ?assertEqual(fallback, Island(0, Max)),
    ?assertEqual(fallback, Island(-1, 10)),
    %% (at most 4096 member-substeps, fewer where half a time slice is up)
    ?assertMatch({T1, _, [_, _], none, []} when T1 > 0 andalso T1 =< 2048, Island(0, 1 bsl 62)).

%% The C compiler's flags that keep the results those of the Erlang code
%% come last, whatever CFLAGS the make command line gives.
exact_float_flags_stay_test() ->
    CSrc = filename:join(code:lib_dir(rigidwarp), "../../../../apps/rigidwarp/c_src"),
    Out = os:cmd("make -n -B -C " ++ CSrc ++ " 'CFLAGS=-O3 -ffast-math -ffp-contract=fast' 2>&1"),
    [Line] = [L || L <- string:split(Out, "
", all), string:find(L, "rw_native.c") =/= nomatch],
    Words = string:lexemes(Line, " "),
    After = fun(Flag) -> lists:nthtail(length(lists:takewhile(fun(W) -> W =/= Flag end, Words)), Words) end,
    ?assertMatch(["-ffast-math" | _], After("-ffast-math")),
    ?assert(lists:member("-fno-fast-math", After("-ffast-math"))),
    ?assert(lists:member("-ffp-contract=off", After("-ffp-contract=fast"))).

%% A library built for a host whose byte order is not little-endian refuses
%% to load, and the Erlang code runs: in a VM that finds only such a
%% build, rw_native says it is not loaded and the scan answers as the
%% Erlang code does. (The same build without the refusal loads there.)
big_endian_build_refuses_to_load_test_() ->
    {timeout, 120,
     fun() ->
             Still = rw_states:pack([#st{p = {0.0, 0.0, 0.0}, v = {0.0, 0.0, 0.0}} || _ <- lists:seq(1, 5)],
                                    undefined, false, false),
             Near = rw_states:pack([#st{p = {3.0 - K, 0.0, 0.0}, v = {-1.0, 0.0, 0.0}} || K <- lists:seq(0, 4)],
                                   undefined, false, false),
             Args = [Still, 1, Near, 1, 4, 1.0],
             Expected = rw_states:first_touch(Still, 1, Near, 1, 4, 1.0),
             ?assert(is_integer(Expected)),
             ?assertEqual({false, Expected}, with_build("-DRW_HOST_LITTLE_ENDIAN=0", Args)),
             ?assertEqual({true, Expected}, with_build("", Args))
     end}.

%% The library built with Defines into a temporary directory, loaded by a
%% VM that finds no other (no code path: the modules are loaded into it):
%% whether it loaded, and rw_states:first_touch/6 of Args there.
with_build(Defines, Args) ->
    Dir = string:trim(os:cmd("mktemp -d")),
    CSrc = filename:join(code:lib_dir(rigidwarp), "../../../../apps/rigidwarp/c_src"),
    try
        Log = os:cmd("make -s -B -C " ++ CSrc ++ " PRIV=" ++ Dir ++ " 'CFLAGS=-O2 " ++ Defines ++ "' 2>&1; echo $?"),
        ?assertEqual("0", lists:last(string:lexemes(Log, "
"))),
        {ok, Peer, _} = peer:start_link(#{connection => standard_io, env => [{rw_native:library_variable(), Dir}]}),
        try
            _ = [begin
                     {M, Bin, File} = code:get_object_code(M),
                     {module, M} = peer:call(Peer, code, load_binary, [M, File, Bin])
                 end || M <- [rw_priv, rw_trace, rw_native, rw_states]],
            {peer:call(Peer, rw_native, loaded, []), peer:call(Peer, rw_states, first_touch, Args)}
        after
            peer:stop(Peer)
        end
    after
        os:cmd("rm -rf " ++ Dir)
    end.

%% huge_pages/0 advises the VM's super carrier: 1 GiB in a VM started with
%% +MMscs 1024 (with at most a few MiB the kernel merged into its mapping;
%% where Linux leaves huge pages to the program, the mapping is then
%% eligible for them), nothing in one without.
huge_pages_test_() ->
    case sanitized() of
        true -> [];
        false ->
            {timeout, 60,
             fun() ->
                     Advised = advised(["+MMscs", "1024", "+MMsco", "false"]),
                     ?assert(Advised >= 1 bsl 30 andalso Advised < (1 bsl 30) + (64 bsl 20)),
                     ?assertEqual(0, advised([]))
             end}
    end.

%% Under make sanitize the sanitizers' runtime has mappings of its own of
%% a GiB and more, which huge_pages/0 advises too: the counts here are
%% those of a VM without it.
sanitized() -> string:find(os:getenv("LD_PRELOAD", ""), "libasan") =/= nomatch.

%% A simulation asks for them from 5000 bodies on (where the system leaves
%% huge pages to programs, the carrier is eligible only then).
huge_pages_for_large_simulations_test_() ->
    {timeout, 60,
     fun() ->
             case madvise_mode() andalso not sanitized() of
                 true ->
                     ?assertEqual([false], eligible_after(4999)),
                     ?assertEqual([true], eligible_after(5000));
                 false ->
                     ok
             end
     end}.

%% huge_pages/0 in a peer VM started with Flags: the bytes it advised, which
%% are those of the carriers, each then eligible for huge pages where the
%% system leaves them to programs.
advised(Flags) ->
    {Advised, Carriers} = in_peer(Flags, fun(Peer) -> peer:call(Peer, rw_native, huge_pages, []) end),
    ?assertEqual(lists:sum([Size || {Size, _} <- Carriers]), Advised),
    case madvise_mode() of
        true -> ?assertEqual([true || _ <- Carriers], [Eligible || {_, Eligible} <- Carriers]);
        false -> ok
    end,
    Advised.

%% Whether each carrier may have huge pages once a simulation of Bodies
%% bodies asked for them.
eligible_after(Bodies) ->
    {ok, Carriers} = in_peer(["+MMscs", "1024", "+MMsco", "false"],
                             fun(Peer) -> peer:call(Peer, rw_native, huge_pages_for, [Bodies]) end),
    [Eligible || {_, Eligible} <- Carriers].

%% Fun(Peer) in a peer VM started with Flags, and that VM's carriers after it.
in_peer(Flags, Fun) ->
    {ok, Peer, _} = peer:start_link(#{connection => standard_io, args => Flags ++ ["-pa" | code:get_path()]}),
    try
        Result = Fun(Peer),
        {ok, Smaps} = file:read_file("/proc/" ++ peer:call(Peer, os, getpid, []) ++ "/smaps"),
        {Result, carriers(Smaps)}
    after
        peer:stop(Peer)
    end.

%% Linux leaves transparent huge pages to programs (its setting "madvise").
madvise_mode() ->
    case file:read_file("/sys/kernel/mm/transparent_hugepage/enabled") of
        {ok, <<"always [madvise] never", _/binary>>} -> true;
        _ -> false
    end.

%% The private anonymous read-write mappings of at least 1 GiB in smaps, and
%% whether each may have huge pages.
carriers(Smaps) ->
    Lines = binary:split(Smaps, <<"\n">>, [global]),
    carriers(Lines, []).

carriers([], Acc) -> lists:reverse(Acc);
carriers([Line | Rest], Acc) ->
    Size = case re:run(Line, "^([0-9a-f]+)-([0-9a-f]+) rw-p [0-9a-f]+ [0-9a-f:]+ 0\\s*$", [{capture, all_but_first, list}]) of
               {match, [A, B]} -> list_to_integer(B, 16) - list_to_integer(A, 16);
               nomatch -> 0
           end,
    case Size >= 1 bsl 30 of
        true ->
            Eligible = [E || L <- lists:takewhile(fun(L) -> re:run(L, "^[0-9a-f]+-") =:= nomatch end, Rest),
                             {match, [E]} <- [re:run(L, "^THPeligible:\\s+([01])", [{capture, all_but_first, binary}])]],
            carriers(Rest, [{Size, Eligible =:= [<<"1">>]} | Acc]);
        false ->
            carriers(Rest, Acc)
    end.
