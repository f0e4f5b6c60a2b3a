%% rw_output in temporary directories: renames, resumes cut at the
%% checkpoint's line, refusals, and outputs written in place (FIFO,
%% character devices made with mknod) that stay what they were.
-module(rw_output_tests).
-include_lib("eunit/include/eunit.hrl").
-include_lib("kernel/include/file.hrl").
-include_lib("rw_physics/include/rw_physics.hrl").

-define(FP, <<"fingerprint-1">>).

frame(T) ->
    {frame, T, [{<<"a">>, {float(T), 2.0, -0.0}, {1.0, 0.5, 0.0}, undefined, undefined},
                {<<"b">>, {0.0, 1.0, 2.0}, {0.0, 0.0, 0.0}, {{0.0, 0.0, 0.0}, 1.0}, {0.0, 1.0, 0.0}}]}.

states(T) ->
    [#st{p = {float(T), 2.0, 0.0}, v = {1.0, 0.5, 0.0}},
     #st{p = {0.0, 1.0, 2.0}, v = {0.0, 0.0, 0.0}, q = {{0.0, 0.0, 0.0}, 1.0}, w = {0.0, 1.0, 0.0}}].

ckpt(T) -> {checkpoint, T * 1000, T, states(T)}.

lines(Ts) -> iolist_to_binary([rw_frames:encode(frame(T)) || T <- Ts]).

%% Frames Ts into Out, a checkpoint right after each frame in Ckpts.
write(Out, Ts, Ckpts) ->
    lists:foldl(fun(T, O) ->
                        O1 = rw_output:frame(O, frame(T)),
                        case lists:member(T, Ckpts) of
                            true -> rw_output:checkpoint(O1, ckpt(T));
                            false -> O1
                        end
                end, Out, Ts).

tmpdir() -> string:trim(os:cmd("mktemp -d /tmp/rw_output_tests.XXXXXX")).

cleanup(Dir) ->
    _ = os:cmd("umount " ++ Dir ++ "/ro 2>/dev/null"),
    _ = os:cmd("chmod -R u+w " ++ Dir ++ "; rm -rf " ++ Dir),
    ok.

in_tmp(Test) -> {setup, fun tmpdir/0, fun cleanup/1, fun(Dir) -> ?_test(Test(Dir)) end}.

ls(Dir) -> lists:sort(element(2, file:list_dir(Dir))).

type(Path) -> {ok, #file_info{type = T}} = file:read_link_info(Path), T.

sh(Cmd) ->
    {0, Cmd} = {exit_status(Cmd), Cmd},
    ok.

exit_status(Cmd) ->
    Port = open_port({spawn, Cmd}, [exit_status, stderr_to_stdout]),
    status(Port).

status(Port) ->
    receive
        {Port, {data, _}} -> status(Port);
        {Port, {exit_status, S}} -> S
    end.

%% ---------------------------------------------------------------- files

fresh_run_renames_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   {ok, O, fresh} = rw_output:open(F, ?FP, false),
                   ?assertEqual(regular, type(F ++ ".part")),
                   O1 = write(O, lists:seq(0, 9), [3, 7]),
                   ?assertEqual(regular, type(F ++ ".checkpoint")),
                   ok = rw_output:finish(O1),
                   ?assertEqual({ok, lines(lists:seq(0, 9))}, file:read_file(F)),
                   ?assertEqual(["f.jsonl"], ls(Dir))
           end).

%% Many lines: the 64 KiB flushes write whole lines only.
large_run_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   Ts = lists:seq(0, 2999),
                   {ok, O, fresh} = rw_output:open(F, ?FP, false),
                   O1 = write(O, Ts, [1000]),
                   {ok, Part} = file:read_file(F ++ ".part"),
                   ?assert(byte_size(Part) > 65536),
                   ?assertEqual($\n, binary:last(Part)),
                   ok = rw_output:finish(O1),
                   ?assertEqual({ok, lines(Ts)}, file:read_file(F))
           end).

resume_cuts_at_checkpoint_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   {ok, O, fresh} = rw_output:open(F, ?FP, false),
                   ok = rw_output:suspend(write(O, lists:seq(0, 9), [2, 5])),
                   ?assertEqual(["f.jsonl.checkpoint", "f.jsonl.part"], ls(Dir)),
                   %% a kill in the middle of a line
                   {ok, Fd} = file:open(F ++ ".part", [append, raw]),
                   ok = file:write(Fd, <<"{\"t\":10,\"bodies\":[{\"id\":">>),
                   ok = file:close(Fd),
                   {ok, O2, Ckpt} = rw_output:open(F, ?FP, true),
                   ?assertEqual(ckpt(5), Ckpt),
                   ?assertEqual({ok, lines(lists:seq(0, 4))}, file:read_file(F ++ ".part")),
                   ok = rw_output:finish(write(O2, lists:seq(5, 12), [8])),
                   ?assertEqual({ok, lines(lists:seq(0, 12))}, file:read_file(F)),
                   ?assertEqual(["f.jsonl"], ls(Dir))
           end).

%% Resuming twice from the same checkpoint (killed again before the next).
resume_twice_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   {ok, O, fresh} = rw_output:open(F, ?FP, false),
                   ok = rw_output:suspend(write(O, lists:seq(0, 6), [4])),
                   {ok, O2, Ckpt} = rw_output:open(F, ?FP, true),
                   ?assertEqual(ckpt(4), Ckpt),
                   ok = rw_output:suspend(write(O2, lists:seq(4, 7), [])),
                   {ok, O3, Ckpt} = rw_output:open(F, ?FP, true),
                   ok = rw_output:finish(write(O3, lists:seq(4, 9), [])),
                   ?assertEqual({ok, lines(lists:seq(0, 9))}, file:read_file(F))
           end).

fingerprint_mismatch_refused_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   {ok, O, fresh} = rw_output:open(F, ?FP, false),
                   ok = rw_output:suspend(write(O, lists:seq(0, 3), [2])),
                   Before = file:read_file(F ++ ".part"),
                   {error, Msg} = rw_output:open(F, <<"other">>, true),
                   ?assertMatch({match, _}, re:run(Msg, "f.jsonl.part was written by another scene or other options")),
                   ?assertEqual(nomatch, string:find(Msg, "\n")),
                   ?assertEqual(Before, file:read_file(F ++ ".part"))
           end).

%% No usable checkpoint: starting over is always right.
unusable_checkpoint_starts_over_test_() ->
    Cases = [{garbage, fun(C) -> file:write_file(C, <<"not a term">>) end},
             {cut_short, fun(C) -> {ok, B} = file:read_file(C),
                                   file:write_file(C, binary:part(B, 0, byte_size(B) - 7)) end},
             {missing, fun(C) -> file:delete(C) end},
             {bad_state, fun(C) -> rewrite(C, fun(M) -> M#{states := [{st, 1, 2, 3, 4}]} end) end},
             {bad_version, fun(C) -> rewrite(C, fun(M) -> M#{version := 2} end) end},
             {extra_key, fun(C) -> rewrite(C, fun(M) -> M#{more => 1} end) end},
             {offset_past_end, fun(C) -> rewrite(C, fun(M) -> M#{offset := 1 bsl 30} end) end},
             {offset_mid_line, fun(C) -> rewrite(C, fun(#{offset := Off} = M) -> M#{offset := Off + 3} end) end}],
    [{atom_to_list(Name),
      in_tmp(fun(Dir) ->
                     F = filename:join(Dir, "f.jsonl"),
                     {ok, O, fresh} = rw_output:open(F, ?FP, false),
                     ok = rw_output:suspend(write(O, lists:seq(0, 5), [3])),
                     ok = Spoil(F ++ ".checkpoint"),
                     {ok, O2, fresh} = rw_output:open(F, ?FP, true),
                     ?assertEqual({ok, <<>>}, file:read_file(F ++ ".part")),
                     ?assertNot(filelib:is_file(F ++ ".checkpoint")),
                     ok = rw_output:finish(write(O2, lists:seq(0, 5), [])),
                     ?assertEqual({ok, lines(lists:seq(0, 5))}, file:read_file(F))
             end)} || {Name, Spoil} <- Cases].

rewrite(File, Fun) ->
    {ok, B} = file:read_file(File),
    file:write_file(File, term_to_binary(Fun(binary_to_term(B)))).

resume_without_part_is_fresh_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   {ok, O, fresh} = rw_output:open(F, ?FP, true),
                   ok = rw_output:finish(write(O, [0, 1], [])),
                   ?assertEqual({ok, lines([0, 1])}, file:read_file(F)),
                   %% a finished file is not resumed: the run is made again
                   {ok, O2, fresh} = rw_output:open(F, ?FP, true),
                   ok = rw_output:finish(write(O2, [0, 1, 2], [])),
                   ?assertEqual({ok, lines([0, 1, 2])}, file:read_file(F))
           end).

%% A fresh run drops a stale checkpoint, which belongs to other bytes.
fresh_run_drops_old_checkpoint_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   {ok, O, fresh} = rw_output:open(F, ?FP, false),
                   ok = rw_output:suspend(write(O, lists:seq(0, 5), [3])),
                   {ok, O2, fresh} = rw_output:open(F, <<"other">>, false),
                   ?assertNot(filelib:is_file(F ++ ".checkpoint")),
                   ok = rw_output:suspend(write(O2, [0, 1], [])),
                   {ok, _, fresh} = rw_output:open(F, <<"other">>, true)
           end).

symlink_stays_a_link_test_() ->
    in_tmp(fun(Dir) ->
                   Real = filename:join(Dir, "real.jsonl"),
                   Link = filename:join(Dir, "link.jsonl"),
                   ok = file:write_file(Real, <<"old\n">>),
                   ok = file:make_symlink("real.jsonl", Link),
                   {ok, O, fresh} = rw_output:open(Link, ?FP, false),
                   ?assertEqual(regular, type(Real ++ ".part")),
                   ok = rw_output:finish(write(O, [0, 1], [0])),
                   ?assertEqual(symlink, type(Link)),
                   ?assertEqual({ok, lines([0, 1])}, file:read_file(Real)),
                   ?assertEqual(["link.jsonl", "real.jsonl"], ls(Dir))
           end).

%% A checkpoint for a time no frame was written at is a caller's bug.
checkpoint_without_its_frame_test_() ->
    in_tmp(fun(Dir) ->
                   F = filename:join(Dir, "f.jsonl"),
                   {ok, O, fresh} = rw_output:open(F, ?FP, false),
                   ?assertError({rw_output, _}, rw_output:checkpoint(write(O, [0, 1], []), ckpt(7)))
           end).

%% ---------------------------------------------------------------- in place

fifo_written_in_place_test_() ->
    in_tmp(fun(Dir) ->
                   Fifo = filename:join(Dir, "fifo"),
                   ok = sh("mkfifo " ++ Fifo),
                   Self = self(),
                   spawn_link(fun() -> Self ! {read, os:cmd("cat " ++ Fifo)} end),
                   {ok, O, fresh} = rw_output:open(Fifo, ?FP, false),
                   ok = rw_output:finish(write(O, lists:seq(0, 999), [10, 500])),
                   Read = receive {read, R} -> R after 10000 -> error(no_reader) end,
                   ?assertEqual(lines(lists:seq(0, 999)), list_to_binary(Read)),
                   ?assertEqual(other, type(Fifo)),
                   ?assertEqual(["fifo"], ls(Dir))
           end).

char_device_written_in_place_test_() ->
    in_tmp(fun(Dir) ->
                   Null = filename:join(Dir, "null"),
                   ok = sh("mknod " ++ Null ++ " c 1 3"),
                   ok = rw_output:check(Null, false),
                   {ok, O, fresh} = rw_output:open(Null, ?FP, false),
                   ok = rw_output:finish(write(O, lists:seq(0, 2999), [5])),
                   {ok, O2, fresh} = rw_output:open(Null, ?FP, false),
                   ok = rw_output:suspend(write(O2, [0, 1], [])),
                   ?assertMatch({ok, #file_info{type = device, major_device = _}}, file:read_link_info(Null)),
                   ?assertEqual(["null"], ls(Dir)),
                   {error, Msg} = rw_output:check(Null, true),
                   ?assertMatch({match, _}, re:run(Msg, "null: not a regular file"))
           end).

%% A symlink to a device: the device is written, the link is left alone.
link_to_device_test_() ->
    in_tmp(fun(Dir) ->
                   Null = filename:join(Dir, "null"),
                   ok = sh("mknod " ++ Null ++ " c 1 3"),
                   ok = file:make_symlink(Null, filename:join(Dir, "out")),
                   {ok, O, fresh} = rw_output:open(filename:join(Dir, "out"), ?FP, false),
                   ok = rw_output:finish(write(O, [0, 1], [0])),
                   ?assertEqual(["null", "out"], ls(Dir)),
                   ?assertEqual(symlink, type(filename:join(Dir, "out")))
           end).

full_device_raises_test_() ->
    in_tmp(fun(Dir) ->
                   Full = filename:join(Dir, "full"),
                   ok = sh("mknod " ++ Full ++ " c 1 7"),
                   %% past one flush: frame/2 raises
                   {ok, O, fresh} = rw_output:open(Full, ?FP, false),
                   try write(O, lists:seq(0, 2999), []) of
                       _ -> error(no_error)
                   catch error:{rw_output, Msg} ->
                           ?assertMatch({match, _}, re:run(Msg, "^cannot write frames to .*/full: no space left on device$"))
                   end,
                   %% less than a flush: finish/1 says so
                   {ok, O2, fresh} = rw_output:open(Full, ?FP, false),
                   {error, Msg2} = rw_output:finish(write(O2, [0, 1], [])),
                   ?assertMatch({match, _}, re:run(Msg2, "no space left on device")),
                   {ok, O3, fresh} = rw_output:open(Full, ?FP, false),
                   ok = rw_output:suspend(write(O3, [0, 1], [])),
                   ?assertEqual(device, type(Full)),
                   ?assertEqual(["full"], ls(Dir))
           end).

stdout_test() ->
    Self = self(),
    Collector = spawn_link(fun() -> collect(Self, []) end),
    Writer = spawn_link(fun() ->
                                group_leader(Collector, self()),
                                {ok, O, fresh} = rw_output:open("-", ?FP, false),
                                ok = rw_output:finish(write(O, lists:seq(0, 999), [3])),
                                Self ! written
                        end),
    receive written -> ok after 10000 -> error({no_write, Writer}) end,
    Collector ! {done, self()},
    receive {collected, Bin} -> ?assertEqual(lines(lists:seq(0, 999)), Bin) end,
    ?assertMatch({error, _}, rw_output:check("-", true)),
    ?assertEqual(ok, rw_output:check("-", false)).

collect(Parent, Acc) ->
    receive
        {io_request, From, Ref, {put_chars, _, Chars}} ->
            From ! {io_reply, Ref, ok},
            collect(Parent, [Acc, Chars]);
        {io_request, From, Ref, _} ->
            From ! {io_reply, Ref, {error, enotsup}},
            collect(Parent, Acc);
        {done, Pid} -> Pid ! {collected, iolist_to_binary(Acc)}
    end.

%% ---------------------------------------------------------------- refusals

check_test_() ->
    in_tmp(fun(Dir) ->
                   Refused = fun(Path, Resume, Re) ->
                                     {error, Msg} = rw_output:check(Path, Resume),
                                     ?assertEqual(nomatch, string:find(Msg, "\n")),
                                     ?assertMatch({match, _}, re:run(Msg, "^cannot write frames to " ++ Re)),
                                     {error, Msg} = rw_output:open(Path, ?FP, Resume)
                             end,
                   Refused(Dir, false, ".*: is a directory"),
                   Refused(filename:join([Dir, "nodir", "f.jsonl"]), false, ".*nodir does not exist"),
                   ok = file:write_file(filename:join(Dir, "file"), <<>>),
                   Refused(filename:join([Dir, "file", "f.jsonl"]), false, ".*not a directory"),
                   ok = rw_output:check(filename:join(Dir, "new.jsonl"), false),
                   ok = rw_output:check(filename:join(Dir, "new.jsonl"), true),
                   ok = rw_output:check(filename:join(Dir, "file"), true),
                   %% side files in the way that are not regular files
                   ok = file:make_dir(filename:join(Dir, "x.jsonl.part")),
                   Refused(filename:join(Dir, "x.jsonl"), false, ".*x.jsonl.part is in the way"),
                   Fifo = filename:join(Dir, "fifo"),
                   ok = sh("mkfifo " ++ Fifo),
                   Refused(Fifo, true, ".*fifo: not a regular file"),
                   ok = sh("mkfifo " ++ filename:join(Dir, "y.jsonl.checkpoint.tmp")),
                   Refused(filename:join(Dir, "y.jsonl"), false, ".*y.jsonl.checkpoint.tmp is in the way"),
                   ok = file:make_symlink("loop", filename:join(Dir, "loop")),
                   Refused(filename:join(Dir, "loop"), false, ".*too many levels of symbolic links"),
                   %% none of this left anything behind
                   ?assertEqual(["fifo", "file", "loop", "x.jsonl.part", "y.jsonl.checkpoint.tmp"], ls(Dir))
           end).

%% Root writes through mode bits (chmod 0555 does not stop it), so an
%% unwritable directory is made as a read-only mount; mode bits are still
%% honoured for other users (the probe file is what decides).
read_only_directory_test_() ->
    in_tmp(fun(Dir) ->
                   Ro = filename:join(Dir, "ro"),
                   ok = file:make_dir(Ro),
                   case exit_status("mount -t tmpfs -o size=1m none " ++ Ro) of
                       0 ->
                           ok = file:write_file(filename:join(Ro, "old.jsonl"), <<"x\n">>),
                           ok = sh("mount -o remount,ro " ++ Ro),
                           {error, M1} = rw_output:check(filename:join(Ro, "f.jsonl"), false),
                           ?assertMatch({match, _}, re:run(M1, "cannot create files in directory .*/ro \\(read-only file system\\)")),
                           {error, M2} = rw_output:check(filename:join(Ro, "old.jsonl"), false),
                           ?assertMatch({match, _}, re:run(M2, "old.jsonl: (not writable|cannot create files)")),
                           ?assertEqual(["old.jsonl"], ls(Ro)),
                           ok = sh("umount " ++ Ro);
                       _ ->
                           ?debugMsg("mount is not permitted here: read-only directory not tested")
                   end
           end).
