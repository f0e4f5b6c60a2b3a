%% rw_cli_report: the summary's key order and messages kept to one line.
-module(rw_cli_report_tests).
-include_lib("eunit/include/eunit.hrl").

key_order_test_() ->
    Tw = #{max_lvt => 1, gvt => 1, zeta => 0, alpha => 0, frames => 3, scene => <<"s">>, engine => timewarp,
           events => 2, restarts => 0},
    Ref = #{substeps => 1, engine => reference, scene => <<"s">>, resumed_from_ms => 5, fixture_contacts => 0},
    [?_assertEqual([scene, engine, frames, events, restarts, alpha, gvt, max_lvt, zeta], rw_cli_report:key_order(Tw)),
     ?_assertEqual([scene, engine, substeps, fixture_contacts, resumed_from_ms], rw_cli_report:key_order(Ref)),
     ?_assertEqual(<<"{\"scene\":\"s\",\"engine\":\"reference\",\"substeps\":1,\"fixture_contacts\":0,"
                     "\"resumed_from_ms\":5}">>, iolist_to_binary(rw_cli_report:summary_json(Ref)))].

one_line_test_() ->
    [?_assertEqual("a\\nb: cannot read", rw_cli_report:one_line(["a\nb", <<": cannot read">>])),
     ?_assertEqual("tab\\t cr\\r nul\\x00", rw_cli_report:one_line("tab\t cr\r nul" ++ [0])),
     ?_assertEqual("ünï", rw_cli_report:one_line("ünï"))].
