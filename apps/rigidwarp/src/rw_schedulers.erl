%% The schedulers a simulation asks for (the `schedulers` option). The
%% number of schedulers online is one setting of the whole VM, so this
%% process lends it: the first run that asks sets it and the setting from
%% before comes back once the last run holding it has ended or died; a run
%% asking for another number while it is held is refused.
-module(rw_schedulers).
-behaviour(gen_server).
-export([start_link/0, acquire/1, release/0]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-record(s, {
    online = none :: none | pos_integer(),           % the number lent out
    before = none :: none | pos_integer(),           % to put back
    holders = #{} :: #{pid() => reference()}
}).

-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() -> gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% The caller runs with N schedulers online (at most the VM's schedulers)
%% until it calls release/0 or exits.
-spec acquire(pos_integer()) -> ok | {error, string()}.
acquire(N) when is_integer(N), N > 0 -> gen_server:call(?MODULE, {acquire, self(), N}).

-spec release() -> ok.
release() -> gen_server:call(?MODULE, {release, self()}).

-spec init([]) -> {ok, #s{}}.
init([]) -> {ok, #s{}}.

-spec handle_call({acquire, pid(), pos_integer()} | {release, pid()}, gen_server:from(), #s{}) ->
          {reply, ok | {error, string()}, #s{}}.
handle_call({acquire, Pid, N0}, _From, #s{online = Online, holders = H} = S) ->
    N = min(N0, erlang:system_info(schedulers)),
    case Online of
        none ->
            Before = erlang:system_flag(schedulers_online, N),
            {reply, ok, hold(Pid, S#s{online = N, before = Before})};
        N ->
            {reply, ok, hold(Pid, S)};
        _ when map_size(H) =:= 1, is_map_key(Pid, H) ->
            _ = erlang:system_flag(schedulers_online, N),
            {reply, ok, S#s{online = N}};
        _ ->
            {reply, {error, lists:flatten(
                              io_lib:format("schedulers: another simulation runs with ~b schedulers online "
                                            "(a setting of the whole VM); ~b must wait until it ends", [Online, N]))},
             S}
    end;
handle_call({release, Pid}, _From, S) ->
    {reply, ok, drop(Pid, S)}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({'DOWN', _, process, Pid, _}, S) -> {noreply, drop(Pid, S)};
handle_info(_Msg, S) -> {noreply, S}.

hold(Pid, #s{holders = H} = S) when is_map_key(Pid, H) -> S;
hold(Pid, #s{holders = H} = S) -> S#s{holders = H#{Pid => erlang:monitor(process, Pid)}}.

drop(Pid, #s{holders = H} = S) ->
    case maps:take(Pid, H) of
        error -> S;
        {MRef, H1} ->
            erlang:demonitor(MRef, [flush]),
            case map_size(H1) of
                0 ->
                    _ = erlang:system_flag(schedulers_online, S#s.before),
                    #s{};
                _ -> S#s{holders = H1}
            end
    end.
