%% Flags shared by the escript's commands: the options of `rigidwarp run`
%% (also taken by `view --live`), positive integers and times in ms, and
%% times in ms as people write them. A bad flag throws {usage, Message}
%% (a flag missing the one it needs, {bad_input, Message}),
%% which rw_cli:main/1 prints with exit code 2.
-module(rw_cli_args).
-export([parse/1, bad_flag/2, pos_int/2, pos_ms/2, format_ms/1, shell_quote/1]).

-define(VALUE_FLAGS, ["--engine", "--schedulers", "--nodes", "--connect", "--cookie", "--buckets", "--frames", "--until", "--substep",
                      "--stride", "--frame-ms", "--integrator", "--ccd", "--groups", "--group-max",
                      "--speculation-mb", "--native"]).

%% Flags to {SceneFile, Options, Quiet}.
-spec parse([string()]) -> {string(), map(), boolean()}.
parse(Args) -> parse(Args, undefined, #{}, false).

parse([], undefined, _, _) -> throw({usage, "run needs a scene file"});
parse([], _, #{resume := true} = Opts, _) when not is_map_key(frames, Opts) ->
    throw({bad_input, "--resume needs --frames FILE (the file of the run to continue)"});
parse([], _, #{nodes := N, connect := _}, _) when is_integer(N) ->
    throw({usage, "--nodes and --connect do not go together: --connect names the nodes to use besides this one"});
parse([], _, #{cookie := _} = Opts, _) when not is_map_key(connect, Opts) ->
    throw({usage, "--cookie goes with --connect (the peer nodes of --nodes get a cookie of their own)"});
parse([], File, #{connect := Nodes} = Opts, Quiet) ->
    _ = case Opts of
            #{cookie := Cookie} -> os:putenv("RIGIDWARP_COOKIE", Cookie);
            #{} -> true
        end,
    {File, maps:without([connect, cookie], Opts#{nodes => Nodes}), Quiet};
parse([], File, Opts, Quiet) -> {File, Opts, Quiet};
parse(["--quiet" | Rest], F, O, _) -> parse(Rest, F, O, true);
parse(["--resume" | Rest], F, O, Q) -> parse(Rest, F, O#{resume => true}, Q);
parse(["--engine", "reference" | Rest], F, O, Q) -> parse(Rest, F, O#{engine => reference}, Q);
parse(["--engine", "timewarp" | Rest], F, O, Q) -> parse(Rest, F, O#{engine => timewarp}, Q);
parse(["--engine", E | _], _, _, _) -> throw({usage, "--engine must be timewarp or reference, got " ++ E});
parse(["--schedulers", V | Rest], F, O, Q) ->
    N = pos_int("--schedulers", V),
    Max = erlang:system_info(schedulers),
    N =< Max orelse throw({usage, lists:flatten(io_lib:format("--schedulers must be at most ~b here, got ~s",
                                                              [Max, V]))}),
    parse(Rest, F, O#{schedulers => N}, Q);
parse(["--nodes", V | Rest], F, O, Q) ->
    N = pos_int("--nodes", V),
    N =< 64 orelse throw({usage, "--nodes must be at most 64, got " ++ V}),
    parse(Rest, F, O#{nodes => N}, Q);
parse(["--connect", V | Rest], F, O, Q) ->
    Nodes = [string:trim(N) || N <- string:split(V, ",", all), string:trim(N) =/= ""],
    (Nodes =/= [] andalso lists:all(fun(N) -> length(string:split(N, "@")) =:= 2 end, Nodes)) orelse
        throw({usage, "--connect takes node names as name@host, separated by commas, got " ++ V}),
    parse(Rest, F, O#{connect => [list_to_atom(N) || N <- Nodes]}, Q);
parse(["--cookie", V | Rest], F, O, Q) when V =/= "" -> parse(Rest, F, O#{cookie => V}, Q);
parse(["--buckets", V | Rest], F, O, Q) -> parse(Rest, F, O#{buckets => pos_int("--buckets", V)}, Q);
parse(["--frames", Out | Rest], F, O, Q) -> parse(Rest, F, O#{frames => Out}, Q);
parse(["--until", V | Rest], F, O, Q) -> parse(Rest, F, O#{until => pos_ms("--until", V)}, Q);
parse(["--substep", V | Rest], F, O, Q) -> parse(Rest, F, O#{substep => pos_ms("--substep", V)}, Q);
parse(["--stride", V | Rest], F, O, Q) -> parse(Rest, F, O#{stride => pos_ms("--stride", V)}, Q);
parse(["--frame-ms", V | Rest], F, O, Q) -> parse(Rest, F, O#{frame_ms => pos_ms("--frame-ms", V)}, Q);
parse(["--integrator", V | Rest], F, O, Q) ->
    Known = [atom_to_list(I) || I <- rw_integrate:integrators()],
    lists:member(V, Known) orelse
        throw({usage, lists:flatten(["--integrator must be one of ", lists:join(", ", Known), ", got ", V])}),
    parse(Rest, F, O#{integrator => list_to_existing_atom(V)}, Q);
parse(["--ccd", "on" | Rest], F, O, Q) -> parse(Rest, F, O#{ccd => true}, Q);
parse(["--ccd", "off" | Rest], F, O, Q) -> parse(Rest, F, O#{ccd => false}, Q);
parse(["--ccd", V | _], _, _, _) -> throw({usage, "--ccd must be on or off, got " ++ V});
parse(["--groups", "on" | Rest], F, O, Q) -> parse(Rest, F, O#{groups => true}, Q);
parse(["--groups", "off" | Rest], F, O, Q) -> parse(Rest, F, O#{groups => false}, Q);
parse(["--groups", V | _], _, _, _) -> throw({usage, "--groups must be on or off, got " ++ V});
parse(["--group-max", V | Rest], F, O, Q) ->
    N = pos_int("--group-max", V),
    Max = rw_regroup:max_allowed(),
    N =< Max orelse throw({usage, lists:flatten(io_lib:format("--group-max must be at most ~b, got ~s", [Max, V]))}),
    parse(Rest, F, O#{group_max => N}, Q);
parse(["--native", "on" | Rest], F, O, Q) -> parse(Rest, F, O#{native => true}, Q);
parse(["--native", "off" | Rest], F, O, Q) -> parse(Rest, F, O#{native => false}, Q);
parse(["--native", V | _], _, _, _) -> throw({usage, "--native must be on or off, got " ++ V});
parse(["--speculation-mb", V | Rest], F, O, Q) ->
    N = pos_int("--speculation-mb", V),
    N =< 1 bsl 20 orelse throw({usage, "--speculation-mb must be at most 1048576 (1 TiB), got " ++ V}),
    parse(Rest, F, O#{speculation_mb => N}, Q);
parse([[$- | _] = Flag | _], _, _, _) -> bad_flag(Flag, ?VALUE_FLAGS);
parse([File | Rest], undefined, O, Q) -> parse(Rest, File, O, Q);
parse([Extra | _], _, _, _) -> throw({usage, "unexpected argument " ++ Extra}).

%% A flag that a command's parser did not match: one of its ValueFlags given
%% last (without its value), or a flag it does not know.
-spec bad_flag(string(), [string()]) -> no_return().
bad_flag(Flag, ValueFlags) ->
    case lists:member(Flag, ValueFlags) of
        true -> throw({usage, Flag ++ " needs a value"});
        false -> throw({usage, "unknown flag " ++ Flag})
    end.

%% A time in ms: an integer, or a decimal such as 0.5 (the scene checks
%% that it is a whole number of microseconds).
-spec pos_ms(string(), string()) -> number().
pos_ms(Flag, V) ->
    try list_to_integer(V) of
        I when I > 0, I =< 1 bsl 40 -> I;
        _ -> not_ms(Flag, V)
    catch
        error:badarg ->
            try list_to_float(V) of
                X when X > 0.0, X =< 1.0e12 -> X;
                _ -> not_ms(Flag, V)
            catch
                error:badarg -> not_ms(Flag, V)
            end
    end.

-spec not_ms(string(), string()) -> no_return().
not_ms(Flag, V) -> throw({usage, Flag ++ " must be a positive number of ms (such as 2 or 0.5), got " ++ V}).

-spec pos_int(string(), string()) -> pos_integer().
pos_int(Flag, V) ->
    try list_to_integer(V) of
        I when I > 0, I =< 1 bsl 40 -> I;
        _ -> throw({usage, Flag ++ " must be a positive integer, got " ++ V})
    catch
        error:badarg -> throw({usage, Flag ++ " must be a positive integer, got " ++ V})
    end.

%% A time in ms as people write it: 20, 0.5.
-spec format_ms(number()) -> string().
format_ms(T) when is_integer(T) -> integer_to_list(T);
format_ms(T) -> float_to_list(T, [short]).

%% An argument as a POSIX shell reads it back, quoted only where needed.
-spec shell_quote(string()) -> string().
shell_quote("") -> "''";
shell_quote(Arg) ->
    Plain = lists:all(fun(C) -> (C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z) orelse
                                    (C >= $0 andalso C =< $9) orelse lists:member(C, "-_./=:,+@%")
                      end, Arg),
    case Plain of
        true -> Arg;
        false -> "'" ++ lists:flatten(string:replace(Arg, "'", "'\\''", all)) ++ "'"
    end.
