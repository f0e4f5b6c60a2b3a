%% rw_cli_signals in erl_signal_server, driven by the events the runtime
%% sends there (a real SIGTERM to the test VM would stop it if the handler
%% were not in place): stopping signals reach the process, SIGUSR1/2 do not.
-module(rw_cli_signals_tests).
-include_lib("eunit/include/eunit.hrl").

signals_test_() ->
    {setup,
     fun() -> ok end,
     fun(_) ->
             ok = gen_event:delete_handler(erl_signal_server, rw_cli_signals, []),
             ok = gen_event:add_handler(erl_signal_server, erl_signal_handler, [])
     end,
     ?_test(begin
                Self = self(),
                ok = rw_cli_signals:install(Self),
                ?assertEqual([rw_cli_signals], gen_event:which_handlers(erl_signal_server)),
                ?assertEqual(none, rw_cli_signals:received()),
                ok = gen_event:sync_notify(erl_signal_server, sigusr1),
                ok = gen_event:sync_notify(erl_signal_server, sigusr2),
                ok = gen_event:sync_notify(erl_signal_server, sighup),
                ?assertEqual(sighup, rw_cli_signals:received()),
                receive {rw_interrupt, Sig} -> ?assertEqual(sighup, Sig)
                after 1000 -> error({no_interrupt, Self})
                end,
                receive Other -> error({unexpected, Other}) after 100 -> ok end,
                ?assertEqual([129, 131, 143], [rw_cli_signals:exit_code(S) || S <- [sighup, sigquit, sigterm]])
            end)}.
