%% Where a run's frames go, so that an interrupted run can be resumed and a
%% run never harms anything that is not its own.
%%
%% Frames are JSON Lines (rw_frames:encode/1), one line per committed frame.
%% Three kinds of output:
%%   "-"              standard output, written in place, never closed;
%%   a path that exists and is not a regular file (after symlinks: FIFO,
%%                    character device, socket...): opened for writing in
%%                    place, never truncated, renamed, deleted or given side
%%                    files;
%%   a regular file or a missing path: the frames go to TARGET.part and
%%                    finish/1 renames it to TARGET, TARGET being the path
%%                    after symlinks (a link at the path stays a link).
%%                    TARGET.checkpoint holds the latest checkpoint.
%%
%% Lines are buffered and written whole, each write(2) a run of whole lines,
%% so a kill at any moment leaves a prefix of whole lines (a torn last line
%% is possible only if the kernel cuts a write short; resuming truncates to
%% a checkpoint's offset, so it never survives).
%%
%% API, in the order a run calls it:
%%   check(Path, Resume)       the path is usable: no side effects beyond a
%%                             probe file created and deleted in its directory
%%   open(Path, Fingerprint, Resume) -> {ok, Out, fresh | Checkpoint}
%%                             with Resume, a TARGET.part whose checkpoint has
%%                             this Fingerprint is cut back to the line of the
%%                             checkpoint's frame and the run goes on from
%%                             the Checkpoint; a checkpoint of another
%%                             fingerprint is refused; none usable: fresh
%%   frame(Out, Frame)         buffer one line (flushed past 64 KiB)
%%   checkpoint(Out, Ckpt)     the checkpoint handed over right after the
%%                             frame at its time: flush, datasync, then
%%                             replace TARGET.checkpoint atomically (in
%%                             place: only flush)
%%   finish(Out)               the run completed: TARGET.part becomes TARGET
%%   suspend(Out)              the run stopped early: keep .part and
%%                             .checkpoint for a resume
%% A write error raises error({rw_output, Message}), Message one line naming
%% the path and the reason; every {error, Message} is one line too.
-module(rw_output).
-export([check/2, open/3, frame/2, checkpoint/2, finish/1, suspend/1]).
-export_type([out/0, checkpoint/0]).

-include_lib("kernel/include/file.hrl").
-include_lib("rw_physics/include/rw_physics.hrl").

-type checkpoint() :: {checkpoint, Tick :: non_neg_integer(), Ms :: number(), States :: [#st{}]}.

-define(FLUSH_BYTES, 65536).
%% Frames remembered for a checkpoint to find its line by time: a checkpoint
%% comes right after its frame, so a few are plenty.
-define(RECENT, 64).
-define(MAX_LINKS, 32).

-record(out, {
    kind :: stdout | in_place | part,
    name :: string(),                  % the path as given, for messages
    fd :: file:io_device() | standard_io | undefined,
    target = "" :: string(),           % part: the final path, after symlinks
    part = "" :: string(),
    ckpt = "" :: string(),
    fingerprint = <<>> :: binary(),
    buf = [] :: [iodata()],            % lines not written yet, newest first
    buf_bytes = 0 :: non_neg_integer(),
    size = 0 :: non_neg_integer(),     % bytes written plus buffered
    recent = [] :: [{number(), non_neg_integer()}]  % {Ms, line offset}, newest first
}).
-opaque out() :: #out{}.

%% ---------------------------------------------------------------- check

%% Whether frames can go to Path (and, with Resume, be resumed there).
-spec check(file:name_all(), boolean()) -> ok | {error, string()}.
check(Path, Resume) ->
    case checked(name(Path), Resume) of
        {ok, _} -> ok;
        {error, _} = Error -> Error
    end.

%% What Path is (classify/1), once it has passed the checks.
checked(Path, Resume) ->
    case classify(Path) of
        stdout when Resume -> {error, "--resume needs a frames file, not standard output (-)"};
        stdout -> {ok, stdout};
        {error, _} = Error -> Error;
        {in_place, _} when Resume ->
            fail(Path, "not a regular file, so there is nothing to resume");
        {in_place, #file_info{access = A}} = Class when A =:= write; A =:= read_write -> {ok, Class};
        {in_place, _} -> fail(Path, "not writable");
        {part, Target, Info} = Class ->
            case check_part(Path, Target, Info, Resume) of
                ok -> {ok, Class};
                {error, _} = Error -> Error
            end
    end.

check_part(Path, Target, Info, Resume) ->
    Dir = filename:dirname(Target),
    Checks = [fun() -> writable_file(Path, Info) end,
              fun() -> writable_dir(Path, Dir) end,
              fun() -> side_file(Path, Target ++ ".part", Resume) end,
              fun() -> side_file(Path, Target ++ ".checkpoint", Resume) end,
              fun() -> side_file(Path, Target ++ ".checkpoint.tmp", Resume) end],
    first_error(Checks).

first_error([]) -> ok;
first_error([F | Rest]) ->
    case F() of
        ok -> first_error(Rest);
        {error, _} = E -> E
    end.

writable_file(_, missing) -> ok;
writable_file(_, #file_info{access = A}) when A =:= write; A =:= read_write -> ok;
writable_file(Path, _) -> fail(Path, "not writable").

%% The directory must take a new file: the mode bits say nothing for root
%% or a read-only mount, so a probe file is created and deleted.
writable_dir(Path, Dir) ->
    case file:read_file_info(Dir) of
        {ok, #file_info{type = directory}} ->
            Probe = filename:join(Dir, io_lib:format(".rigidwarp-probe-~s-~b",
                                                     [os:getpid(), erlang:unique_integer([positive])])),
            case file:open(Probe, [write, exclusive, raw]) of
                {ok, Fd} ->
                    _ = file:close(Fd),
                    _ = file:delete(Probe),
                    ok;
                {error, Reason} ->
                    fail(Path, io_lib:format("cannot create files in directory ~ts (~ts)",
                                             [Dir, file:format_error(Reason)]))
            end;
        {ok, _} -> fail(Path, io_lib:format("~ts is not a directory", [Dir]));
        {error, enoent} -> fail(Path, io_lib:format("directory ~ts does not exist", [Dir]));
        {error, enotdir} -> fail(Path, io_lib:format("a parent of ~ts is not a directory", [Dir]));
        {error, Reason} -> fail(Path, io_lib:format("directory ~ts: ~ts", [Dir, file:format_error(Reason)]))
    end.

%% TARGET.part, TARGET.checkpoint and its .tmp are replaced and renamed:
%% only ever regular files (on resume, .part is kept and must be writable).
side_file(Path, Side, Resume) ->
    case file:read_link_info(Side) of
        {error, enoent} -> ok;
        {ok, #file_info{type = regular, access = A}} when not Resume; A =:= write; A =:= read_write -> ok;
        {ok, #file_info{type = regular}} -> fail(Path, io_lib:format("~ts is not writable", [Side]));
        {ok, _} -> fail(Path, io_lib:format("~ts is in the way and is not a regular file", [Side]));
        {error, Reason} -> fail(Path, io_lib:format("~ts: ~ts", [Side, file:format_error(Reason)]))
    end.

%% stdout | {in_place, Info} | {part, Target, Info | missing} | {error, Msg}
classify("-") -> stdout;
%% (an empty name would be read as the current directory's TARGET.part,
%% "./.part", and renamed to nothing at the end)
classify("") -> {error, "cannot write frames to an empty path: name a file, or - for standard output"};
classify(Path) ->
    case final_target(Path) of
        {error, _} = Error -> Error;
        {ok, Target} ->
            case file:read_file_info(Target) of
                {ok, #file_info{type = regular} = Info} -> {part, Target, Info};
                {ok, #file_info{type = directory}} -> fail(Path, "is a directory");
                {ok, Info} -> {in_place, Info};
                {error, enoent} -> {part, Target, missing};
                {error, enotdir} -> fail(Path, "a parent is not a directory");
                {error, Reason} -> fail(Path, file:format_error(Reason))
            end
    end.

%% Path with its symlinks followed (up to the first name that is not one,
%% which may not exist).
final_target(Path) -> final_target(Path, ?MAX_LINKS).

final_target(Path, 0) -> fail(Path, "too many levels of symbolic links");
final_target(Path, N) ->
    case file:read_link(Path) of
        {ok, Link} -> final_target(filename:join(filename:dirname(Path), Link), N - 1);
        {error, _} -> {ok, Path}
    end.

%% ---------------------------------------------------------------- open

-spec open(file:name_all(), binary(), boolean()) -> {ok, out(), fresh | checkpoint()} | {error, string()}.
open(Path0, Fingerprint, Resume) when is_binary(Fingerprint), is_boolean(Resume) ->
    Path = name(Path0),
    case checked(Path, Resume) of
        {ok, Class} -> open_checked(Path, Class, Fingerprint, Resume);
        {error, _} = Error -> Error
    end.

open_checked(Path, stdout, _, _) ->
    {ok, #out{kind = stdout, name = Path, fd = standard_io}, fresh};
open_checked(Path, {in_place, _}, _, _) ->
    %% append: no O_TRUNC, and a FIFO is opened for writing only (opening it
    %% blocks until a reader comes, as any writer's would)
    case file:open(Path, [append, raw, binary]) of
        {ok, Fd} -> {ok, #out{kind = in_place, name = Path, fd = Fd}, fresh};
        {error, Reason} -> fail(Path, file:format_error(Reason))
    end;
open_checked(Path, {part, Target, _}, Fingerprint, Resume) ->
    Out = #out{kind = part, name = Path, target = Target, part = Target ++ ".part",
               ckpt = Target ++ ".checkpoint", fingerprint = Fingerprint},
    case Resume andalso filelib:is_regular(Out#out.part) of
        true -> resume(Out);
        false -> start_over(Out)
    end.

resume(#out{part = Part, ckpt = Ckpt, fingerprint = F} = Out) ->
    case read_checkpoint(Ckpt) of
        {ok, #{fingerprint := F, offset := Offset, tick := Tick, ms := Ms, states := States}} ->
            case file:read_file_info(Part) of
                {ok, #file_info{size = Size}} when Size >= Offset ->
                    case cut(Part, Offset) of
                        {ok, Fd, false} ->
                            _ = file:close(Fd),
                            start_over(Out);
                        {ok, Fd, true} ->
                            {ok, Out#out{fd = Fd, size = Offset}, {checkpoint, Tick, Ms, States}};
                        {error, Reason} -> fail(Part, file:format_error(Reason))
                    end;
                _ -> start_over(Out)
            end;
        {ok, #{}} ->
            fail(Out#out.name, io_lib:format("~ts was written by another scene or other options; "
                                             "run without --resume to start over", [Part]));
        error -> start_over(Out)
    end.

%% The part file cut back to Offset, positioned there for writing, and
%% whether Offset is where a line starts (the checkpoint then fits the file).
cut(Part, Offset) ->
    case file:open(Part, [read, write, raw, binary]) of
        {ok, Fd} ->
            Starts = Offset =:= 0 orelse file:pread(Fd, Offset - 1, 1) =:= {ok, <<"\n">>},
            R = case file:position(Fd, Offset) of
                    {ok, Offset} -> file:truncate(Fd);
                    {error, _} = E -> E
                end,
            case R of
                ok -> {ok, Fd, Starts};
                {error, _} -> _ = file:close(Fd), R
            end;
        {error, _} = E -> E
    end.

%% An empty part file; a checkpoint left there belongs to other bytes.
start_over(#out{part = Part, ckpt = Ckpt} = Out) ->
    case file:open(Part, [write, raw, binary]) of
        {ok, Fd} ->
            ok = delete_regular(Ckpt),
            ok = delete_regular(Ckpt ++ ".tmp"),
            {ok, Out#out{fd = Fd, size = 0}, fresh};
        {error, Reason} -> fail(Part, file:format_error(Reason))
    end.

delete_regular(File) ->
    case file:read_link_info(File) of
        {ok, #file_info{type = regular}} -> _ = file:delete(File), ok;
        _ -> ok
    end.

%% ---------------------------------------------------------------- writing

-spec frame(out(), rw_reference:frame()) -> out().
frame(#out{buf = Buf, buf_bytes = B, size = Size, recent = Recent} = Out, {frame, T, _} = Frame) ->
    Line = rw_frames:encode(Frame),
    N = iolist_size(Line),
    Recent1 = case length(Recent) >= 2 * ?RECENT of
                  true -> lists:sublist(Recent, ?RECENT);
                  false -> Recent
              end,
    Out1 = Out#out{buf = [Line | Buf], buf_bytes = B + N, size = Size + N, recent = [{T, Size} | Recent1]},
    case B + N >= ?FLUSH_BYTES of
        true -> flush(Out1);
        false -> Out1
    end.

-spec checkpoint(out(), checkpoint()) -> out().
checkpoint(#out{kind = part, recent = Recent} = Out, {checkpoint, Tick, Ms, States}) ->
    Offset = case lists:keyfind(Ms, 1, Recent) of
                 {_, O} -> O;
                 false -> raise(Out, io_lib:format("checkpoint at t=~p ms follows no frame at that time", [Ms]))
             end,
    #out{fd = Fd} = Out1 = flush(Out),
    ok = ok_or_raise(Out1, file:datasync(Fd)),
    Bin = term_to_binary(#{version => 1, fingerprint => Out#out.fingerprint, tick => Tick, ms => Ms,
                           offset => Offset, states => States}),
    ok = write_checkpoint(Out1, Bin),
    Out1#out{recent = [R || {T, _} = R <- Recent, T >= Ms]};
checkpoint(Out, {checkpoint, _, _, _}) ->
    %% in place: no checkpoint, but a reader gets the lines so far
    flush(Out).

%% Written beside and renamed over, so a kill leaves the old one or the new
%% one, never half of one.
write_checkpoint(#out{ckpt = Ckpt} = Out, Bin) ->
    Tmp = Ckpt ++ ".tmp",
    case file:open(Tmp, [write, raw, binary]) of
        {ok, Fd} ->
            R = case file:write(Fd, Bin) of
                    ok -> file:datasync(Fd);
                    E -> E
                end,
            _ = file:close(Fd),
            ok = ok_or_raise(Out, Tmp, R),
            ok_or_raise(Out, Ckpt, file:rename(Tmp, Ckpt));
        {error, Reason} -> raise_file(Tmp, Reason)
    end.

%% The buffered lines in one write.
flush(#out{buf = []} = Out) -> Out;
flush(#out{fd = Fd, buf = Buf} = Out) ->
    ok = ok_or_raise(Out, file:write(Fd, lists:reverse(Buf))),
    Out#out{buf = [], buf_bytes = 0}.

-spec finish(out()) -> ok | {error, string()}.
finish(#out{kind = stdout} = Out) ->
    try flush(Out) of _ -> ok
    catch error:{rw_output, Msg} -> {error, Msg}
    end;
finish(#out{kind = in_place, fd = Fd} = Out) ->
    try flush(Out) of
        _ -> ok_or_error(Out#out.name, file:close(Fd))
    catch error:{rw_output, Msg} -> _ = file:close(Fd), {error, Msg}
    end;
finish(#out{kind = part, fd = Fd, part = Part, target = Target, ckpt = Ckpt} = Out) ->
    try flush(Out) of
        _ ->
            %% synced before the rename, so a crash cannot leave TARGET empty
            R = case file:datasync(Fd) of
                    ok -> file:close(Fd);
                    E -> _ = file:close(Fd), E
                end,
            case ok_or_error(Part, R) of
                ok ->
                    case file:rename(Part, Target) of
                        ok ->
                            ok = delete_regular(Ckpt),
                            ok = delete_regular(Ckpt ++ ".tmp");
                        {error, Reason} ->
                            {error, oneline(io_lib:format("cannot rename ~ts to ~ts: ~ts",
                                                          [Part, Target, file:format_error(Reason)]))}
                    end;
                Error -> Error
            end
    catch error:{rw_output, Msg} -> _ = file:close(Fd), {error, Msg}
    end.

-spec suspend(out()) -> ok.
suspend(#out{kind = Kind, fd = Fd} = Out) ->
    _ = try flush(Out) catch error:{rw_output, _} -> ok end,
    _ = Kind =/= stdout andalso file:close(Fd),
    ok.

%% ---------------------------------------------------------------- checkpoints

%% The checkpoint file's map, every field checked; error when missing,
%% unreadable or malformed.
read_checkpoint(File) ->
    case file:read_file(File) of
        {ok, Bin} ->
            try binary_to_term(Bin, [safe]) of
                #{version := 1, fingerprint := F, tick := Tick, ms := Ms, offset := Off, states := States} = M
                  when is_binary(F), is_integer(Tick), Tick >= 0, is_number(Ms), Ms >= 0,
                       is_integer(Off), Off >= 0, is_list(States), map_size(M) =:= 6 ->
                    case lists:all(fun valid_state/1, States) of
                        true -> {ok, M};
                        false -> error
                    end;
                _ -> error
            catch error:badarg -> error
            end;
        {error, _} -> error
    end.

valid_state(#st{p = P, v = V, q = Q, w = W}) ->
    vec(P) andalso vec(V) andalso
        ((Q =:= undefined andalso W =:= undefined) orelse (quat(Q) andalso vec(W)));
valid_state(_) -> false.

vec({X, Y, Z}) -> is_float(X) andalso is_float(Y) andalso is_float(Z);
vec(_) -> false.

quat({V, W}) -> vec(V) andalso is_float(W);
quat(_) -> false.

%% ---------------------------------------------------------------- errors

name(Path) when is_binary(Path) -> unicode:characters_to_list(Path);
name(Path) when is_list(Path) -> lists:flatten(Path);
name(Path) when is_atom(Path) -> atom_to_list(Path).

-spec fail(string(), iodata()) -> {error, string()}.
fail(Path, Problem) ->
    {error, oneline(io_lib:format("cannot write frames to ~ts: ~ts", [Path, Problem]))}.

ok_or_error(_, ok) -> ok;
ok_or_error(File, {error, Reason}) -> fail(File, file:format_error(Reason)).

ok_or_raise(#out{kind = stdout} = Out, R) -> ok_or_raise(Out, "standard output", R);
ok_or_raise(#out{kind = in_place, name = Name} = Out, R) -> ok_or_raise(Out, Name, R);
ok_or_raise(#out{part = Part} = Out, R) -> ok_or_raise(Out, Part, R).

ok_or_raise(_, _, ok) -> ok;
ok_or_raise(_, File, {error, Reason}) -> raise_file(File, Reason).

-spec raise_file(string(), term()) -> no_return().
raise_file(File, Reason) ->
    {error, Msg} = fail(File, file:format_error(Reason)),
    error({rw_output, Msg}).

-spec raise(out(), iodata()) -> no_return().
raise(#out{name = Name}, Problem) ->
    {error, Msg} = fail(Name, Problem),
    error({rw_output, Msg}).

oneline(Chars) ->
    lists:flatten(string:replace(unicode:characters_to_list(Chars), "\n", " ", all)).
