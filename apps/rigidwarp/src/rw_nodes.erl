%% The nodes of a simulation over several Erlang nodes: peer nodes started
%% for a run (OTP's peer: separate OS processes, distribution over TCP on
%% the loopback interface) or nodes already running, with the engine's
%% code loaded from this node so that every node runs the same engine.
-module(rw_nodes).
-export([start/2, alive/1, stop/1, link/1, unlink/1, check/1]).
-export_type([spec/0, nodes/0]).

%% How many nodes in all (this one and peers started for the run), or the
%% nodes to use besides this one.
-type spec() :: pos_integer() | [node()].
%% This node first, then the others; the peers started, to be stopped.
-type nodes() :: #{nodes := [node()], peers := [{node(), pid()}]}.

%% The applications whose code every node needs.
-define(APPS, [rw_physics, rigidwarp]).
-define(CONNECT_MS, 10000).
%% The escript's memory flags (rebar.config, Makefile's VM_FLAGS): a peer
%% is as fast a node as the one that starts it.
-define(PEER_FLAGS, ["+sbtu", "+MMscs", "4096", "+MMsco", "false"]).

%% Is Spec a valid spec, and if not, why.
-spec check(term()) -> ok | {error, string()}.
check(N) when is_integer(N), N >= 1, N =< 64 -> ok;
check(N) when is_integer(N) -> {error, "nodes must be between 1 and 64"};
check([]) -> ok;
check([_ | _] = Nodes) ->
    case lists:all(fun is_atom/1, Nodes) andalso lists:all(fun(N) -> lists:member($@, atom_to_list(N)) end, Nodes) of
        true -> ok;
        false -> {error, "nodes must be a count or a list of node names (name@host)"}
    end;
check(_) -> {error, "nodes must be a count or a list of node names (name@host)"}.

%% Start (a count) or connect to (names) the nodes of a run, with the
%% schedulers each peer started here gets (undefined: the host's), and
%% load the engine on each.
-spec start(spec(), pos_integer() | undefined) -> {ok, nodes()} | {error, string()}.
start(1, _Schedulers) ->
    {ok, #{nodes => [node()], peers => []}};
start([], Schedulers) ->
    start(1, Schedulers);
start(N, Schedulers) when is_integer(N) ->
    case distributed(loopback) of
        ok -> start_peers(N - 1, Schedulers, []);
        {error, _} = Error -> Error
    end;
start(Names, _Schedulers) ->
    case distributed({like, hd(Names)}) of
        ok -> connect([N || N <- Names, N =/= node()], []);
        {error, _} = Error -> Error
    end.

%% The nodes of a run still reachable, this one first.
-spec alive(nodes()) -> [node()].
alive(#{nodes := Nodes}) -> [N || N <- Nodes, N =:= node() orelse lists:member(N, erlang:nodes())].

%% Stop the peers started for the run.
-spec stop(#{peers := [{node(), pid()}], atom() => term()}) -> ok.
stop(#{peers := Peers}) ->
    _ = [catch peer:stop(Pid) || {_, Pid} <- Peers],
    ok.

%% The peers' control processes are linked to the process that started
%% them: a run takes them over (link/1 in the run, unlink/1 in the
%% starter), and they stop with it.
-spec link(nodes()) -> ok.
link(#{peers := Peers}) ->
    _ = [erlang:link(Pid) || {_, Pid} <- Peers],
    ok.

-spec unlink(nodes()) -> ok.
unlink(#{peers := Peers}) ->
    _ = [erlang:unlink(Pid) || {_, Pid} <- Peers],
    ok.

%%% Internals

%% This node must be distributed: if it is not, it becomes so under a name
%% of its own: on the loopback interface when every node is a local peer,
%% with a random cookie unless RIGIDWARP_COOKIE sets one; else named after
%% this host as the nodes to join are (long or short names), with their
%% cookie (RIGIDWARP_COOKIE, else ~/.erlang.cookie).
distributed(Where) ->
    case is_alive() of
        true -> ok;
        false ->
            {Host, Domain} = case Where of
                                 loopback ->
                                     ok = application:set_env(kernel, inet_dist_use_interface, {127, 0, 0, 1}),
                                     {"127.0.0.1", longnames};
                                 {like, Node} ->
                                     [_, Theirs] = string:split(atom_to_list(Node), "@"),
                                     case lists:member($., Theirs) of
                                         true -> {net_adm:localhost(), longnames};
                                         false -> {hd(string:split(net_adm:localhost(), ".")), shortnames}
                                     end
                             end,
            ok = application:set_env(kernel, prevent_overlapping_partitions, false),
            Name = list_to_atom("rigidwarp_" ++ os:getpid() ++ "_" ++ integer_to_list(erlang:unique_integer([positive]))
                                ++ "@" ++ Host),
            case start_distribution(Name, Domain) of
                ok ->
                    _ = case os:getenv("RIGIDWARP_COOKIE") of
                            Cookie when is_list(Cookie), Cookie =/= "" -> erlang:set_cookie(list_to_atom(Cookie));
                            _ when Where =:= loopback ->
                                case init:get_argument(setcookie) of
                                    {ok, _} -> true;
                                    error -> erlang:set_cookie(random_cookie())
                                end;
                            _ -> true
                        end,
                    ok;
                {error, _} = Error ->
                    Error
            end
    end.

%% net_kernel needs an epmd to register with: one is started if none
%% answers, as `erl -name' does.
start_distribution(Name, Domain) ->
    _ = case erl_epmd:names() of
            {ok, _} -> ok;
            {error, _} -> start_epmd()
        end,
    case net_kernel:start(Name, #{name_domain => Domain}) of
        {ok, _} -> ok;
        {error, Reason} ->
            {error, lists:flatten(io_lib:format("cannot make this node distributed (is epmd running?): ~0p", [Reason]))}
    end.

start_epmd() ->
    ErtsBin = filename:join([code:root_dir(), "erts-" ++ erlang:system_info(version), "bin"]),
    case [E || E <- [os:find_executable("epmd", ErtsBin), os:find_executable("epmd")], E =/= false] of
        [Epmd | _] ->
            _ = os:cmd(Epmd ++ " -daemon"),
            timer:sleep(200);
        [] ->
            error
    end.

random_cookie() ->
    list_to_atom(lists:flatten([io_lib:format("~2.16.0b", [B]) || <<B>> <= crypto:strong_rand_bytes(16)])).

start_peers(0, _Schedulers, Acc) ->
    Peers = lists:reverse(Acc),
    {ok, #{nodes => [node() | [N || {N, _} <- Peers]], peers => Peers}};
start_peers(K, Schedulers, Acc) ->
    Host = case string:split(atom_to_list(node()), "@") of [_, H] -> H; _ -> "127.0.0.1" end,
    %% no transitive connections, and no node disconnecting the others
    %% when one goes away: a run stays connected to the nodes it has left
    Args = ["-setcookie", atom_to_list(erlang:get_cookie()), "-connect_all", "false",
            "-kernel", "prevent_overlapping_partitions", "false" | ?PEER_FLAGS]
        ++ loopback(Host)
        ++ case Schedulers of undefined -> []; S -> ["+S", integer_to_list(S)] end,
    %% the peer runs with these flags only, not those of the environment
    Opts = #{name => peer:random_name(rigidwarp), host => Host, longnames => lists:member($., Host), args => Args,
             env => [{"ERL_FLAGS", ""}, {"ERL_AFLAGS", ""}, {"ERL_ZFLAGS", ""}], wait_boot => 30000},
    case catch peer:start_link(Opts) of
        {ok, Pid, Node} ->
            case load(Node) of
                ok -> start_peers(K - 1, Schedulers, [{Node, Pid} | Acc]);
                {error, _} = Error -> stop(#{peers => [{Node, Pid} | Acc]}), Error
            end;
        Other ->
            stop(#{peers => Acc}),
            {error, lists:flatten(io_lib:format("cannot start a peer node: ~0p", [Other]))}
    end.

%% A peer listens on the loopback interface when its host name is a
%% loopback address (always so when this node made itself distributed).
loopback(Host) ->
    case inet:getaddr(Host, inet) of
        {ok, {127, _, _, _} = Addr} -> ["-kernel", "inet_dist_use_interface", lists:flatten(io_lib:format("~w", [Addr]))];
        _ -> []
    end.

connect([], Acc) ->
    {ok, #{nodes => [node() | lists:reverse(Acc)], peers => []}};
connect([Node | Rest], Acc) ->
    _ = case os:getenv("RIGIDWARP_COOKIE") of
            Cookie when is_list(Cookie), Cookie =/= "" -> erlang:set_cookie(Node, list_to_atom(Cookie));
            _ -> true
        end,
    case net_kernel:connect_node(Node) of
        true ->
            case load(Node) of
                ok -> connect(Rest, [Node | Acc]);
                {error, _} = Error -> Error
            end;
        _ ->
            {error, lists:flatten(io_lib:format("cannot connect to node ~ts (is it running, with the same cookie, "
                                                "and are epmd's port 4369 and its distribution port open?)",
                                                [Node]))}
    end.

%% Load this node's engine on Node: its modules' object code, so that
%% every node runs the same engine whatever it has installed, and its C
%% loops' library (rw_native), copied into a temporary directory of Node
%% for the module to load and removed again (where Node cannot load it,
%% it runs the Erlang code: the same results).
load(Node) ->
    _ = [application:load(App) || App <- ?APPS],
    Mods = lists:append([Ms || App <- ?APPS, {ok, Ms} <- [application:get_key(App, modules)]]),
    try
        Library = ship_native(Node),
        try
            lists:foreach(fun(M) ->
                                  {M, Bin, File} = code:get_object_code(M),
                                  {module, M} = erpc:call(Node, code, load_binary, [M, File, Bin], ?CONNECT_MS)
                          end, Mods)
        after
            unship_native(Node, Library)
        end
    of
        ok -> ok
    catch
        Class:Reason ->
            {error, lists:flatten(io_lib:format("cannot load the engine on ~ts: ~0p", [Node, {Class, Reason}]))}
    end.

%% The library's file on Node, where rw_native's loader looks
%% (rw_native:library_variable/0), or none.
ship_native(Node) ->
    case rw_native:library() of
        {ok, Lib} ->
            Tmp = erpc:call(Node, os, getenv, ["TMPDIR", "/tmp"], ?CONNECT_MS),
            Dir = filename:join(Tmp, "rigidwarp-native-" ++ integer_to_list(erlang:unique_integer([positive]))
                                ++ "-" ++ os:getpid()),
            File = filename:join(Dir, "rw_native.so"),
            case erpc:call(Node, file, make_dir, [Dir], ?CONNECT_MS) =:= ok andalso
                erpc:call(Node, file, write_file, [File, Lib], ?CONNECT_MS) =:= ok of
                true ->
                    true = erpc:call(Node, os, putenv, [rw_native:library_variable(), Dir], ?CONNECT_MS),
                    {Dir, File};
                false ->
                    none
            end;
        none ->
            none
    end.

unship_native(_Node, none) -> ok;
unship_native(Node, {Dir, File}) ->
    _ = erpc:call(Node, os, unsetenv, [rw_native:library_variable()], ?CONNECT_MS),
    _ = erpc:call(Node, file, delete, [File], ?CONNECT_MS),
    _ = erpc:call(Node, file, del_dir, [Dir], ?CONNECT_MS),
    ok.
