%% Runs the model of the Time Warp protocol (rw_entity_prop, proper_statem
%% over the pure rw_entity, no processes) from common_test, failing with
%% the shrunk counterexample.
-module(rw_entity_prop_SUITE).
-include_lib("common_test/include/ct.hrl").
-export([all/0, suite/0, end_per_testcase/2]).
-export([protocol/1]).

%% Random runs of the model; each is a scene, a group setting and a
%% random delivery order of a few hundred messages and steps.
-define(NUMTESTS, 500).

suite() -> [{timetrap, {minutes, 10}}].

all() -> [protocol].

end_per_testcase(_Case, _Config) ->
    proper:global_state_erase(),
    ok.

protocol(_Config) ->
    case proper:quickcheck(rw_entity_prop:prop_protocol(), [{numtests, ?NUMTESTS}, {to_file, user}, long_result]) of
        true ->
            %% (scripts/run-tests reads this line for its closing count)
            io:format(user, "protocol model: ~b runs passed~n", [?NUMTESTS]),
            {comment, io_lib:format("~b runs", [?NUMTESTS])};
        Counterexample ->
            ct:pal("the protocol model failed; counterexample:~n~p", [Counterexample]),
            ct:fail({protocol, Counterexample})
    end.
