%% Top supervisor of the rigidwarp application.
%%
%%   rigidwarp_sup (one_for_one)
%%   |-- rw_schedulers: lends the VM's schedulers_online to the runs that ask
%%   `-- rw_sims_sup: one rw_run per Time Warp simulation (rw_sim_sup draws
%%       the rest of the tree)
%%
%% The reference engine runs in the caller's process and needs no children.
-module(rigidwarp_sup).
-behaviour(supervisor).
-export([start_link/0, init/1]).

-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() -> supervisor:start_link({local, ?MODULE}, ?MODULE, []).

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    {ok, {#{strategy => one_for_one, intensity => 5, period => 10},
          [#{id => rw_schedulers, start => {rw_schedulers, start_link, []}, type => worker, shutdown => 1000},
           #{id => rw_sims_sup, start => {rw_sims_sup, start_link, []}, type => supervisor,
             shutdown => infinity}]}}.
