%% What the escript reports while and after a scene runs, for `run` and
%% `view --live` alike: the progress line on stderr, the summary as one
%% JSON object with its keys in a fixed order, and messages kept to one line;
%% and the files the benchmarks write, each whole or not at all.
-module(rw_cli_report).
-include_lib("rigidwarp/include/rigidwarp.hrl").
-export([progress/2, is_terminal/0, summary_json/1, key_order/1, live_summary/2, one_line/1, write_atomically/2]).

%% The summary's keys in the order they are printed: these first (those
%% the run has), then any others sorted. The run help text lists the same
%% order (cli_SUITE checks that it does).
-define(COMMON_KEYS, [scene, engine, bodies, substep_ms, stride_ms, sim_ms, wall_ms, realtime_factor, frames, native]).
-define(TIMEWARP_KEYS, [effective_stride_ms, throttled, memory_holds, events, antievents, rollbacks, primary_rollbacks, secondary_rollbacks, rolled_back_substeps,
                        computed_substeps, committed_substeps, efficiency, steps, regroups, restarts,
                        nodes, cross_node_messages, cross_node_bytes, cross_node_messages_per_s,
                        cross_node_bytes_per_s, migrations, resumed_from_ms]).
-define(REFERENCE_KEYS, [substeps, body_substeps, pair_contacts, fixture_contacts, resumed_from_ms]).

%% The progress line on stderr: redrawn in place (4 times a second) on a
%% terminal, a plain line every 2 s otherwise (CI logs, pipes), and always
%% a last one at the end. Returns the on_progress option and a function
%% that ends the line.
-spec progress(number(), boolean()) -> {#{on_progress := fun((map()) -> ok)}, fun(() -> ok)}.
progress(Total, Tty) ->
    Key = {?MODULE, progress},
    put(Key, {undefined, ""}),
    Every = case Tty of true -> 250; false -> 2000 end,
    Fun = fun(#{gvt := G, wall_ms := Wall} = P) ->
                  Now = erlang:monotonic_time(millisecond),
                  {Last, _} = get(Key),
                  case Last =:= undefined orelse Now - Last >= Every orelse G >= Total of
                      true ->
                          Line = progress_line(Total, P, Wall),
                          put(Key, {Now, Line}),
                          case Tty of
                              true -> io:put_chars(standard_error, ["\r\e[K", Line]);
                              false -> io:put_chars(standard_error, [Line, $\n])
                          end;
                      false -> ok
                  end
          end,
    Finish = fun() ->
                     _ = Tty andalso element(2, get(Key)) =/= "" andalso io:put_chars(standard_error, "\n"),
                     ok
             end,
    {#{on_progress => Fun}, Finish}.

progress_line(Total, #{gvt := G, realtime_factor := Rt} = P, Wall) ->
    Eta = case G > 0 of
              true -> io_lib:format("  ETA ~.1f s", [(Total - G) * Wall / G / 1000]);
              false -> ""
          end,
    Engine = case P of
                 #{max_lvt := MaxLvt, rollbacks := Rb} ->
                     io_lib:format("  GVT lag ~s ms  rollbacks ~b", [rw_cli_args:format_ms(max(0, MaxLvt - G)), Rb]);
                 _ -> ""
             end,
    lists:flatten(io_lib:format("rigidwarp: t=~s/~s ms  realtime x~.2f~s~s",
                                [rw_cli_args:format_ms(max(G, 0)), rw_cli_args:format_ms(Total), float(Rt), Engine, Eta])).

%% stderr on a terminal? (io:columns/0 cannot tell in an escript on OTP 25.)
-spec is_terminal() -> boolean().
is_terminal() ->
    case file:read_link("/proc/" ++ os:getpid() ++ "/fd/2") of
        {ok, "/dev/pts/" ++ _} -> true;
        {ok, "/dev/tty" ++ _} -> true;
        _ -> false
    end.

%% A summary as one JSON object (no newline), its keys in key_order/1.
-spec summary_json(map()) -> iodata().
summary_json(Summary) ->
    jiffy:encode({[{K, maps:get(K, Summary)} || K <- key_order(Summary)]}).

%% The keys of a summary in the order they are printed.
-spec key_order(map()) -> [atom()].
key_order(Summary) ->
    Fixed = ?COMMON_KEYS ++ case maps:get(engine, Summary, timewarp) of
                                reference -> ?REFERENCE_KEYS;
                                _ -> ?TIMEWARP_KEYS
                            end,
    [K || K <- Fixed, is_map_key(K, Summary)] ++ lists:sort(maps:keys(maps:without(Fixed, Summary))).

%% The summary of a live run (rigidwarp:start/2 of Scene) from its
%% rigidwarp:stats/1 at the end: the keys and meaning of `run`'s summary.
%% A started run begins at t=0 and commits a frame every frame_ms and one
%% at its end.
-spec live_summary(#scene{}, map()) -> map().
live_summary(#scene{name = Name, substep = Dt, stride = Stride, frame = Frame, duration = End, spheres = Spheres} = Scene,
             #{wall_ms := Wall} = Stats) ->
    SimMs = rw_scene:duration_ms(Scene),
    %% as run's summary: without the progress figures of a run under way
    (maps:without([status, gvt, start_ms, end_ms, max_lvt], Stats))#{scene => Name, engine => timewarp, bodies => length(Spheres),
                                     substep_ms => rw_scene:ms(Scene, Dt), stride_ms => rw_scene:ms(Scene, Stride),
                                     sim_ms => SimMs, wall_ms => Wall, realtime_factor => SimMs / max(Wall, 0.001),
                                     frames => (End + Frame - 1) div Frame + 1}.

%% A message as one line: control characters (a newline in a file name)
%% shown escaped, so that every message is a single line of text.
-spec one_line(unicode:chardata()) -> string().
one_line(Msg) ->
    lists:flatmap(fun($\n) -> "\\n";
                     ($\r) -> "\\r";
                     ($\t) -> "\\t";
                     (C) when C < 32; C =:= 127 -> io_lib:format("\\x~2.16.0B", [C]);
                     (C) -> [C]
                  end, text(Msg)).

text(Msg) ->
    case unicode:characters_to_list(Msg) of
        L when is_list(L) -> L;
        _ -> lists:flatten(io_lib:format("~0p", [Msg]))
    end.

%% Write File whole or not at all (through File.part); a file that cannot
%% be written is bad input.
-spec write_atomically(string(), iodata()) -> ok.
write_atomically(File, Data) ->
    Tmp = File ++ ".part",
    case filelib:ensure_dir(File) =:= ok andalso file:write_file(Tmp, Data) of
        ok -> file:rename(Tmp, File);
        _ -> throw({bad_input, "cannot write " ++ File})
    end.
