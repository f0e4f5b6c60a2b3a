%% Run by `rebar3 shell` (rebar.config: {shell, [{script_file, ...}]}) once the
%% rigidwarp application is up: a short hint of what to type.
main(_) ->
    io:put_chars(
      "\nrigidwarp shell. Try:\n"
      "  rigidwarp:run(\"scenarios/head_on_elastic.json\", #{}).         % run to the end, get a summary\n"
      "  {ok, Sim} = rigidwarp:start(\"scenarios/bouncing_200_250.json\", #{}).\n"
      "  rigidwarp:stats(Sim).  rigidwarp:view(Sim).  rigidwarp:stop(Sim).\n"
      "  rigidwarp:help().                                               % the whole API\n\n").
