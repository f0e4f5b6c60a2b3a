%% Where the rigidwarp application's priv directory is: the application's
%% own or, from the rigidwarp escript (whose archive holds no priv
%% directory that files could be served or a library loaded from), the
%% build's, beside the escript's bin directory. The viewer's files and the
%% C loops' library are there.
-module(rw_priv).
-export([dir/0]).

-spec dir() -> file:filename().
dir() ->
    Priv = code:priv_dir(rigidwarp),
    case is_list(Priv) andalso filelib:is_dir(Priv) of
        true -> Priv;
        false ->
            Script = filename:absname(escript:script_name()),
            filename:join([filename:dirname(filename:dirname(Script)), "lib", "rigidwarp", "priv"])
    end.
