%% Scene arguments and the scene list. A command's SCENE is a file, or a
%% bundled scene's NAME looked up as scenarios/NAME.json in the current
%% directory and then in the checkout whose _build/PROFILE/bin holds the
%% escript (so that `rigidwarp run projectile` works from anywhere).
-module(rw_cli_scene).
-include_lib("kernel/include/file.hrl").
-include_lib("rigidwarp/include/rigidwarp.hrl").
-export([resolve/1, list/1, closest/2, wrap/2]).

-define(WIDTH, 100).

%% The file for a scene argument: an existing file as it is, a path or a
%% .json name as it is (loading it says what is wrong), else the first
%% scenarios/NAME.json found. An unknown NAME throws bad_input naming the
%% places looked at and the closest names.
-spec resolve(string()) -> string().
resolve(Arg) ->
    Arg =:= "" andalso throw({usage, "the scene argument is empty"}),
    case is_file(Arg) orelse lists:member($/, Arg) orelse lists:suffix(".json", Arg) of
        true -> Arg;
        false ->
            Candidates = [filename:join(Dir, Arg ++ ".json") || Dir <- scene_dirs()],
            case [F || F <- Candidates, filelib:is_regular(F)] of
                [File | _] -> File;
                [] -> throw({bad_input, unknown(Arg, Candidates)})
            end
    end.

is_file(Path) ->
    case file:read_file_info(Path) of
        {ok, #file_info{type = directory}} -> false;
        {ok, _} -> true;
        {error, _} -> false
    end.

unknown(Name, Candidates) ->
    Known = lists:usort([filename:basename(F, ".json")
                         || Dir <- scene_dirs(), F <- filelib:wildcard(filename:join(Dir, "*.json"))]),
    Closest = case closest(Name, Known) of
                  [] -> "";
                  Names -> ["; closest: ", lists:join(", ", Names)]
              end,
    lists:flatten([Name, ": no such scene (looked for ", lists:join(", ", [Name | Candidates]), ")", Closest,
                   "; rigidwarp scenes lists the scenes"]).

%% Where a scene NAME is looked for: scenarios in the current directory,
%% then in the checkout the escript was built in (when it runs from
%% _build/PROFILE/bin), each directory once.
scene_dirs() ->
    Here = "scenarios",
    case project_dir() of
        {ok, Project} ->
            There = filename:join(Project, "scenarios"),
            case filename:absname(Here) =:= There of
                true -> [Here];
                false -> [Here, There]
            end;
        none -> [Here]
    end.

project_dir() ->
    %% script_name/0 fails outside an escript (in the tests' VM)
    case catch escript:script_name() of
        Script when is_list(Script), Script =/= [] ->
            Bin = filename:dirname(filename:absname(follow(Script, 8))),
            case lists:reverse(filename:split(Bin)) of
                ["bin", _Profile, "_build" | Up] when Up =/= [] -> {ok, normal(lists:reverse(Up))};
                _ -> none
            end;
        _ -> none
    end.

%% An absolute path's components without . and .. (as cwd-relative
%% candidates are shown, without detours).
normal(Parts) ->
    filename:join(lists:reverse(lists:foldl(fun(".", Acc) -> Acc;
                                               ("..", [Root]) -> [Root];
                                               ("..", [_ | Acc]) -> Acc;
                                               (P, Acc) -> [P | Acc]
                                            end, [], Parts))).

%% Path with its symbolic links followed (an escript linked into ~/bin).
follow(Path, 0) -> Path;
follow(Path, N) ->
    case file:read_link(Path) of
        {ok, Target} -> follow(filename:absname(Target, filename:dirname(filename:absname(Path))), N - 1);
        {error, _} -> Path
    end.

%% The known names nearest to Name: those containing it first, then those
%% a few edits away, nearest first, at most five.
-spec closest(string(), [string()]) -> [string()].
closest(Name, Known) ->
    Limit = max(2, length(Name) div 3),
    Near = lists:sort([{Outside, D, K} || K <- Known,
                                          Outside <- [string:find(K, Name) =:= nomatch],
                                          D <- [distance(Name, K)],
                                          D =< Limit orelse not Outside]),
    [K || {_, _, K} <- lists:sublist(Near, 5)].

%% Levenshtein distance.
distance(A, B) ->
    First = lists:seq(0, length(B)),
    lists:last(lists:foldl(fun({I, CA}, Prev) -> row(CA, B, Prev, [I]) end, First,
                           lists:zip(lists:seq(1, length(A)), A))).

row(_CA, [], _Prev, Acc) -> lists:reverse(Acc);
row(CA, [CB | Bs], [Diag, Up | Prev], [Left | _] = Acc) ->
    Cost = case CA =:= CB of true -> 0; false -> 1 end,
    row(CA, Bs, [Up | Prev], [min(min(Left + 1, Up + 1), Diag + Cost) | Acc]).

%%% The scene list

%% `rigidwarp scenes [DIR]`: for every scene file, a line with its body
%% count, duration and the box its bodies start in, then its whole
%% description, indented.
-spec list(file:filename() | default) -> 0.
list(default) ->
    Dirs = scene_dirs(),
    case [D || D <- Dirs, filelib:wildcard(filename:join(D, "*.json")) =/= []] of
        [Dir | _] -> list(Dir);
        [] -> throw({bad_input, lists:flatten(["no scene files in " | lists:join(" or ", Dirs)])})
    end;
list(Dir) ->
    Files = lists:sort(filelib:wildcard(filename:join(Dir, "*.json"))),
    Files =:= [] andalso throw({bad_input, "no scene files in " ++ Dir}),
    [io:put_chars(describe(F, rigidwarp:load(F, #{}))) || F <- Files],
    0.

%% One scene's entry in the list.
describe(File, {ok, #scene{spheres = Spheres, initial = Initial} = Scene}) ->
    Name = filename:basename(File),
    N = length(Spheres),
    Bodies = io_lib:format("~5b ~-6s", [N, case N of 1 -> "body"; _ -> "bodies" end]),
    Head = io_lib:format("~-24ts ~s ~6s ms  ~ts", [Name, Bodies, rw_cli_args:format_ms(rw_scene:duration_ms(Scene)),
                                                   start_box([P || #st{p = P} <- Initial])]),
    [string:trim(Head, trailing), $\n,
     [["    ", L, $\n] || L <- wrap(description(File), ?WIDTH - 4)]];
describe(File, {error, Msg}) ->
    [io_lib:format("~-24ts INVALID: ~ts", [filename:basename(File), rw_cli_report:one_line(Msg)]), $\n].

%% Where the bodies start: one point, or the box from the least to the
%% greatest initial coordinates.
start_box([]) -> "";
start_box([P]) -> ["at ", point(P)];
start_box(Ps) ->
    {Xs, Ys, Zs} = lists:foldl(fun({X, Y, Z}, {AX, AY, AZ}) -> {[X | AX], [Y | AY], [Z | AZ]} end, {[], [], []}, Ps),
    ["in ", point({lists:min(Xs), lists:min(Ys), lists:min(Zs)}), "..",
     point({lists:max(Xs), lists:max(Ys), lists:max(Zs)})].

point({X, Y, Z}) -> ["[", lists:join(",", [coordinate(C) || C <- [X, Y, Z]]), "]"].

%% To the centimetre, without trailing zeros: 2.9, -0.05, 1.
coordinate(C) ->
    R = round(C * 100),
    case R rem 100 of
        0 -> integer_to_list(R div 100);
        _ -> float_to_list(R / 100, [{decimals, 2}, compact])
    end.

description(File) ->
    try
        {ok, Bin} = file:read_file(File),
        #{<<"description">> := D} = jiffy:decode(Bin, [return_maps]),
        unicode:characters_to_list(D)
    of
        Text when is_list(Text) -> Text;
        _ -> ""
    catch
        _:_ -> ""
    end.

%% Text in lines of at most Width characters, broken between words (a word
%% longer than that gets a line of its own).
-spec wrap(string(), pos_integer()) -> [string()].
wrap(Text, Width) ->
    case string:lexemes(Text, " \t\r\n") of
        [] -> [];
        [First | Words] ->
            {Lines, Last} = lists:foldl(fun(W, {Done, Line}) ->
                                                case string:length(Line) + 1 + string:length(W) =< Width of
                                                    true -> {Done, Line ++ " " ++ W};
                                                    false -> {[Line | Done], W}
                                                end
                                        end, {[], First}, Words),
            lists:reverse([Last | Lines])
    end.
