%% OS signals while `rigidwarp run` simulates: a gen_event handler in
%% erl_signal_server, in place of OTP's default one (which runs init:stop/0
%% on SIGTERM, killing the run midway with a stack trace, and halts with a
%% crash dump on SIGUSR1).
%%
%% SIGTERM, SIGHUP and SIGQUIT send {rw_interrupt, Signal} to the process
%% running the command, which stops the simulation, keeps what it wrote
%% resumable and exits 128 + the signal's number; a second one of them
%% halts at once, in case the run does not stop. SIGUSR1 and SIGUSR2 are
%% ignored: the run goes on.
%%
%% SIGINT cannot be handled on OTP 25 (os:set_signal(sigint, handle) is
%% badarg) and the runtime exits 130 at once: what holds then is only that
%% the frames file is a prefix of whole lines with a checkpoint beside it,
%% so that --resume continues it.
-module(rw_cli_signals).
-behaviour(gen_event).
-export([install/1, received/0, exit_code/1]).
-export([init/1, handle_event/2, handle_call/2]).

-type signal() :: sigterm | sighup | sigquit.
-export_type([signal/0]).

-define(STOPPING, [sigterm, sighup, sigquit]).
-define(IGNORED, [sigusr1, sigusr2]).

%% From now on the stopping signals go to Pid as {rw_interrupt, Signal}.
-spec install(pid()) -> ok.
install(Pid) ->
    %% removed first: for an instant no handler acts, rather than both
    _ = gen_event:delete_handler(erl_signal_server, erl_signal_handler, []),
    ok = gen_event:add_handler(erl_signal_server, ?MODULE, Pid),
    lists:foreach(fun(Sig) -> ok = os:set_signal(Sig, handle) end, ?STOPPING ++ ?IGNORED).

%% The first stopping signal received, if any.
-spec received() -> signal() | none.
received() ->
    case catch gen_event:call(erl_signal_server, ?MODULE, received, 5000) of
        Sig when is_atom(Sig) -> Sig;
        _ -> none
    end.

%% A shell's status for a process that the signal stopped.
-spec exit_code(signal()) -> pos_integer().
exit_code(sighup) -> 129;
exit_code(sigquit) -> 131;
exit_code(sigterm) -> 143.

-spec init(pid()) -> {ok, {pid(), signal() | none}}.
init(Pid) -> {ok, {Pid, none}}.

-spec handle_event(term(), {pid(), signal() | none}) -> {ok, {pid(), signal() | none}}.
handle_event(Sig, {Pid, none}) ->
    case lists:member(Sig, ?STOPPING) of
        true ->
            Pid ! {rw_interrupt, Sig},
            {ok, {Pid, Sig}};
        false ->
            {ok, {Pid, none}}
    end;
handle_event(Sig, {_, First} = State) ->
    case lists:member(Sig, ?STOPPING) of
        true ->
            io:format(standard_error, "rigidwarp: ~s again, stopping at once~n", [signal_name(Sig)]),
            erlang:halt(exit_code(First));
        false ->
            {ok, State}
    end.

-spec handle_call(received, {pid(), signal() | none}) -> {ok, signal() | none, {pid(), signal() | none}}.
handle_call(received, {_, Sig} = State) -> {ok, Sig, State}.

signal_name(Sig) -> string:uppercase(atom_to_list(Sig)).
