%% The shell API's option table: what help/0 prints is what load/2 checks,
%% and every refusal is one line.
-module(rigidwarp_tests).
-include_lib("eunit/include/eunit.hrl").

scene() -> filename:join(code:lib_dir(rigidwarp), "../../../../scenarios/head_on_elastic.json").

%% A value of each kind that check accepts, and one it refuses.
good(ms) -> 1;
good(count) -> 2;
good({count, Max}) -> Max;
good(non_neg) -> 0;
good(boolean) -> true;
good(path) -> "x.jsonl";
good(callback) -> fun(_) -> ok end;
good(nodes) -> 2;
good({one_of, [A | _]}) -> A.

bad(ms) -> -1;
bad(count) -> 0;
bad({count, Max}) -> Max + 1;
bad(non_neg) -> -1;
bad(boolean) -> yes;
bad(path) -> 42;
bad(callback) -> fun() -> ok end;
bad(nodes) -> [not_a_node_name];
bad({one_of, _}) -> "not one of them".

every_option_is_checked_as_the_table_says_test_() ->
    [{atom_to_list(K),
      fun() ->
              ?assertMatch({ok, _}, rigidwarp:load(scene(), #{K => good(Kind)})),
              {error, Message} = rigidwarp:load(scene(), #{K => bad(Kind)}),
              ?assertEqual(1, length(string:split(Message, "\n", all))),
              ?assertMatch({match, _}, re:run(Message, "^bad value for option " ++ atom_to_list(K) ++ ": "))
      end} || {K, Kind, _} <- rigidwarp:options()].

unknown_option_is_one_line_test() ->
    {error, Message} = rigidwarp:load(scene(), #{untill => 5}),
    ?assertEqual(nomatch, string:find(Message, "\n")),
    [?assertNotEqual(nomatch, string:find(Message, atom_to_list(K))) || {K, _, _} <- rigidwarp:options()].

help_lists_every_option_test() ->
    Leader = group_leader(),
    Text = try
               group_leader(capture(self()), self()),
               ok = rigidwarp:help(),
               receive {captured, T} -> T after 1000 -> <<>> end
           after
               group_leader(Leader, self())
           end,
    [?assertNotEqual(nomatch, string:find(Text, ["    ", atom_to_list(K), " "])) || {K, _, _} <- rigidwarp:options()].

%% A group leader that collects what is written and hands it over once.
capture(Owner) ->
    spawn_link(fun() -> capture_loop(Owner, []) end).

capture_loop(Owner, Acc) ->
    receive
        {io_request, From, Ref, {put_chars, unicode, Chars}} ->
            From ! {io_reply, Ref, ok},
            Owner ! {captured, iolist_to_binary(lists:reverse([Chars | Acc]))},
            capture_loop(Owner, [Chars | Acc]);
        {io_request, From, Ref, {put_chars, unicode, M, F, A}} ->
            Chars = apply(M, F, A),
            From ! {io_reply, Ref, ok},
            Owner ! {captured, iolist_to_binary(lists:reverse([Chars | Acc]))},
            capture_loop(Owner, [Chars | Acc])
    end.
