%% An entity's step ahead (pure): its members integrated substep by substep
%% from their states at LVT up to LVT_ub, assuming no contact with the
%% outside other than those already known, as the island steps them
%% (rw_island), with the post-response velocities at each sync point passed
%% on the way (to commit once the step is written).
-module(rw_chain).
-include("rigidwarp.hrl").
-export([run/5, run_each/5, pack/2]).
-export_type([context/0, passed/0]).

%% Substeps to go before asking the C loop again where it took none.
-define(NATIVE_AGAIN, 16).

%% What a step needs besides the states: the model, the substep, the
%% members' post-response velocities at the point where their group was
%% formed (they come from their old entities), the known contacts and the
%% sync calendar.
-type context() :: {#model{}, pos_integer(), none | {non_neg_integer(), tuple()}, rw_timeline:timeline(),
                    rw_sync:calendar()}.
%% A sync point passed: the members' states and post-response velocities.
-type passed() :: {non_neg_integer(), tuple(), tuple()}.

%% The members' states after T up to Last (per member, rw_states:packed()
%% of one state per substep), the sync points passed on the way, and the
%% island with its neighbour list. A body alone flies free through
%% flight/26 (with CCD it is stepped substep by substep, its states kept
%% in a list and packed at the end: a step of at most a stride); a group
%% appends each member's states to a binary as it computes them, so that
%% the states of a long step are never on the heap for the garbage
%% collector to copy. Where the C loops are loaded (rw_native) the C
%% island takes a group's substeps, and a body's alone where it touches a
%% fixture, but for the group's start.
-spec run(non_neg_integer(), tuple(), non_neg_integer(), context(), rw_island:island()) ->
          {[passed()], [rw_states:packed()], rw_island:island()}.
run(T, {St}, Last, {#model{ccd = false, rotation = Rot}, _, Base, TL, Cal} = Ctx, Island0) when T < Last ->
    %% the substeps at which the body does not fly free: its group's
    %% start, and known contacts with the outside
    Busy = lists:usort([TB || {TB, _} <- [Base], TB >= T, TB < Last] ++ rw_timeline:contact_times(T, Last, TL)),
    #st{p = {X, Y, Z}, v = {VX, VY, VZ}, q = Q, w = W} = St,
    try flight(T, X, Y, Z, VX, VY, VZ, Q, W, Last, Ctx, rw_island:free_zone(Island0), Island0, rw_sync:next_at(T, Cal),
               Busy, [], <<>>, none, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, native()) of
        {Passed, Bin, Extents, Reach, Island} -> {Passed, [rw_states:packed(Bin, Rot, Extents, Reach)], Island}
    catch
        %% (a move between states too far apart for a double: the reach is
        %% measured as rw_states:pack/4 measures it)
        error:badarith -> run_each(T, St, Last, Ctx, Island0)
    end;
run(T, {St}, Last, Ctx, Island0) ->
    run_each(T, St, Last, Ctx, Island0);
run(T, States, Last, {#model{rotation = Rot, ccd = Ccd}, _, _, TL, _} = Ctx, Island0) ->
    %% (the C island, where it is loaded, takes the substeps but the
    %% group's start, given the known contacts with the outside)
    Native = case Ccd =:= false andalso rw_native:enabled() of
                 true -> rw_timeline:contact_times(T, Last, TL);
                 false -> false
             end,
    {Passed, Bins, Island} = chain(T, States, Last, Ctx, Island0, [], [<<>> || _ <- tuple_to_list(States)], Native),
    {Passed, [rw_states:seal(Bin, Rot, Ccd) || Bin <- Bins], Island}.

%% A body on its own, stepped substep by substep through its island: what
%% run/5 computes for it.
-spec run_each(non_neg_integer(), #st{}, non_neg_integer(), context(), rw_island:island()) ->
          {[passed()], [rw_states:packed()], rw_island:island()}.
run_each(T, St, Last, {M, _, _, _, _} = Ctx, Island0) ->
    {Passed, States, Island} = alone(T, St, Last, Ctx, Island0, [], []),
    {Passed, [pack(States, M)], Island}.

%% States packed (with CCD, with their free displacements).
-spec pack([#st{}, ...], #model{}) -> rw_states:packed().
pack(States, #model{rotation = Rot, ccd = false}) -> rw_states:pack(States, undefined, Rot, false);
pack(States, #model{rotation = Rot} = M) -> rw_states:pack(States, [disp(St, M) || St <- States], Rot, true).

%% Bin with St appended (and with CCD its free displacement).
add(Bin, St, #model{rotation = Rot} = M) -> rw_states:append(Bin, St, disp(St, M), Rot).

%% What the packed states hold of St's free displacement: with CCD, the
%% displacement; without, nothing.
disp(_St, #model{ccd = false}) -> undefined;
disp(St, M) -> rw_integrate:free_displacement(M, St).

%% Each member's binary with its state in States appended.
add_all(_K, _States, [], _M) -> [];
add_all(K, States, [Bin | Bins], M) -> [add(Bin, element(K, States), M) | add_all(K + 1, States, Bins, M)].

%% A body on its own, substep by substep.
alone(T, _St, Last, _Ctx, Island, Passed, Acc) when T >= Last ->
    {lists:reverse(Passed), lists:reverse(Acc), Island};
alone(T, St, Last, {_, Dt, _, _, Cal} = Ctx, Island0, Passed, Acc) ->
    {Post, Next, Island} = substep(T, St, Ctx, Island0),
    Passed1 = case rw_sync:is_sync(T, Cal) of
                  true -> [{T, {St}, {Post}} | Passed];
                  false -> Passed
              end,
    alone(T + Dt, Next, Last, Ctx, Island, Passed1, [Next | Acc]).

%% A body's post-response velocities at T and its next state.
substep(T, St, {M, _, Base, TL, _}, Island0) ->
    {{V, W, U} = Post, Island} = case Base of
                                     {T, {BasePost}} -> {BasePost, Island0};
                                     _ -> rw_island:post(Island0, St, rw_timeline:external(T, TL))
                                 end,
    {Post, rw_integrate:advance(M, St, V, W, U), Island}.

%% A body on its own without CCD, the hot path of free flight: while it
%% touches nothing it keeps its velocities, and a substep is a few float
%% operations (rw_integrate:move/10 with a zero pseudo-velocity) and the
%% state appended to the binary. So is a
%% substep near a fixture that the body does not touch (the island's own
%% test, rw_island:touches_no_fixture/4). Other substeps (a fixture
%% touched, a known contact, the group's start) go through the island as
%% in alone/7. Sync is the next sync point, Busy the substeps known not to
%% be free. The free substeps up to the next sync point or busy substep
%% are the C loop's (rw_native:free_run/13: the same operations) where it
%% can tell them free (in the free zone, or near fixtures it can test), one
%% at a time here where it cannot. Native is false (Erlang alone), 0 (try
%% the C loop) or how many substeps to go before trying it again: a body
%% resting on the floor is never free, and the C loop would be asked in
%% vain at every substep.
flight(T, _X, _Y, _Z, _VX, _VY, _VZ, _Q, _W, Last, _Ctx, _Zone, Island, _Sync, _Busy, Passed, Bin,
       _PX, X0, Y0, Z0, X1, Y1, Z1, Reach, _Native) when T >= Last ->
    {lists:reverse(Passed), Bin, {X0, Y0, Z0, X1, Y1, Z1}, Reach, Island};
flight(T, X, Y, Z, VX, VY, VZ, Q, W, Last, {#model{dt = Dt, gravity = G, integrator = Int}, DtT, _, _, _} = Ctx,
       Zone, Island, Sync, Busy, Passed, Bin, First, X0, Y0, Z0, X1, Y1, Z1, Reach, 0)
  when T =/= Sync ->
    Next = case Busy of
               [B | _] -> B;
               [] -> none
           end,
    %% (without a free zone, where the island's own test finds the body
    %% touching none of the fixtures near it)
    Free = case Zone of
               none -> rw_island:near_zone(Island);
               _ -> Zone
           end,
    case Next =/= T andalso Free =/= none andalso
        rw_native:free_run(T, Last, DtT, Dt, Sync, Next, Free, G, Int, {X, Y, Z, VX, VY, VZ}, Q, W,
                           {First, {X0, Y0, Z0, X1, Y1, Z1}, Reach}) of
        false ->
            flight_one(T, X, Y, Z, VX, VY, VZ, Q, W, Last, Ctx, Zone, Island, Sync, Busy, Passed, Bin, First,
                       X0, Y0, Z0, X1, Y1, Z1, Reach, 0);
        {T1, {NX, NY, NZ, NVX, NVY, NVZ}, NQ, States, {First1, {NX0, NY0, NZ0, NX1, NY1, NZ1}, Reach1}} when T1 > T ->
            Bin1 = <<Bin/binary, States/binary>>,
            case T1 >= Last of
                true -> flight(T1, NX, NY, NZ, NVX, NVY, NVZ, NQ, W, Last, Ctx, Zone, Island, Sync, Busy, Passed, Bin1,
                               First1, NX0, NY0, NZ0, NX1, NY1, NZ1, Reach1, 0);
                false -> flight_one(T1, NX, NY, NZ, NVX, NVY, NVZ, NQ, W, Last, Ctx, Zone, Island, Sync, Busy, Passed,
                                    Bin1, First1, NX0, NY0, NZ0, NX1, NY1, NZ1, Reach1, 0)
            end;
        _ when Next =/= T ->
            %% touching a fixture: the C island (Busy holds the times of
            %% the known contacts, and the group's start)
            case native_island(T, Last, Ctx, Island, {#st{p = {X, Y, Z}, v = {VX, VY, VZ}, q = Q, w = W}},
                               {First, {X0, Y0, Z0, X1, Y1, Z1}, Reach}, Busy) of
                {T1, {#st{p = {NX, NY, NZ}, v = {NVX, NVY, NVZ}, q = NQ, w = NW}}, [States],
                 {First1, {NX0, NY0, NZ0, NX1, NY1, NZ1}, Reach1}, More} when T1 > T ->
                    {_, _, _, _, Cal} = Ctx,
                    flight(T1, NX, NY, NZ, NVX, NVY, NVZ, NQ, NW, Last, Ctx, Zone, Island, rw_sync:next_at(T1, Cal),
                           [B || B <- Busy, B >= T1], lists:reverse(More, Passed), <<Bin/binary, States/binary>>,
                           First1, NX0, NY0, NZ0, NX1, NY1, NZ1, Reach1, 0);
                _ ->
                    flight_one(T, X, Y, Z, VX, VY, VZ, Q, W, Last, Ctx, Zone, Island, Sync, Busy, Passed, Bin, First,
                               X0, Y0, Z0, X1, Y1, Z1, Reach, ?NATIVE_AGAIN)
            end;
        _ ->
            flight_one(T, X, Y, Z, VX, VY, VZ, Q, W, Last, Ctx, Zone, Island, Sync, Busy, Passed, Bin, First,
                       X0, Y0, Z0, X1, Y1, Z1, Reach, ?NATIVE_AGAIN)
    end;
flight(T, X, Y, Z, VX, VY, VZ, Q, W, Last, Ctx, Zone, Island, Sync, Busy, Passed, Bin, First, X0, Y0, Z0, X1, Y1, Z1,
       Reach, Native) ->
    flight_one(T, X, Y, Z, VX, VY, VZ, Q, W, Last, Ctx, Zone, Island, Sync, Busy, Passed, Bin, First, X0, Y0, Z0, X1, Y1,
               Z1, Reach, if is_integer(Native), Native > 0 -> Native - 1; true -> Native end).

%% Native at the start of a flight.
native() ->
    case rw_native:enabled() of
        true -> 0;
        false -> false
    end.

%% One substep of flight/26, in Erlang.
flight_one(T, X, Y, Z, VX, VY, VZ, Q, W, Last, {#model{dt = Dt} = M, DtT, _, _, Cal} = Ctx,
       Zone, Island, Sync, Busy, Passed0, Bin, First, X0, Y0, Z0, X1, Y1, Z1, Reach, Native)
  when is_float(X), is_float(Y), is_float(Z), is_float(VX), is_float(VY), is_float(VZ), is_float(Dt) ->
    {Post, NX, NY, NZ, NVX, NVY, NVZ, NQ, NW, Zone1, Island1} =
        case is_free(T, X, Y, Z, Zone, Busy, Island) of
            true ->
                {AX, AY, AZ, AVX, AVY, AVZ} = rw_integrate:move(M, X, Y, Z, VX, VY, VZ, 0.0, 0.0, 0.0),
                AQ = case W of
                         undefined -> Q;
                         _ -> rw_quat:integrate(Q, W, Dt)
                     end,
                {free, AX, AY, AZ, AVX, AVY, AVZ, AQ, W, Zone, Island};
            false ->
                St = #st{p = {X, Y, Z}, v = {VX, VY, VZ}, q = Q, w = W},
                {P, #st{p = {AX, AY, AZ}, v = {AVX, AVY, AVZ}, q = AQ, w = AW}, I1} = substep(T, St, Ctx, Island),
                {P, AX, AY, AZ, AVX, AVY, AVZ, AQ, AW, rw_island:free_zone(I1), I1}
        end,
    {Passed, Sync1} =
        case T =:= Sync of
            true ->
                %% (a free body's post-response velocities are its own)
                SyncPost = case Post of
                               free -> {{VX, VY, VZ}, W, {0.0, 0.0, 0.0}};
                               _ -> Post
                           end,
                {[{T, {#st{p = {X, Y, Z}, v = {VX, VY, VZ}, q = Q, w = W}}, {SyncPost}} | Passed0],
                 rw_sync:next_at(T + DtT, Cal)};
            false ->
                {Passed0, Sync}
        end,
    Busy1 = case Busy of
                [T | More] -> More;
                _ -> Busy
            end,
    Bin1 = append(Bin, NX, NY, NZ, NVX, NVY, NVZ, NQ, NW),
    case First of
        none ->
            %% the first state: the box is its position, the reach 0 (as
            %% rw_states:pack/4 measures them)
            flight(T + DtT, NX, NY, NZ, NVX, NVY, NVZ, NQ, NW, Last, Ctx, Zone1, Island1, Sync1, Busy1, Passed, Bin1,
                   some, NX, NY, NZ, NX, NY, NZ, 0.0, Native);
        _ when is_float(NX), is_float(NY), is_float(NZ), is_float(X0), is_float(Y0), is_float(Z0), is_float(X1),
               is_float(Y1), is_float(Z1), is_float(Reach) ->
            Step = abs(NX - X) + abs(NY - Y) + abs(NZ - Z),
            flight(T + DtT, NX, NY, NZ, NVX, NVY, NVZ, NQ, NW, Last, Ctx, Zone1, Island1, Sync1, Busy1, Passed, Bin1,
                   some, if NX < X0 -> NX; true -> X0 end, if NY < Y0 -> NY; true -> Y0 end,
                   if NZ < Z0 -> NZ; true -> Z0 end, if NX > X1 -> NX; true -> X1 end,
                   if NY > Y1 -> NY; true -> Y1 end, if NZ > Z1 -> NZ; true -> Z1 end,
                   if Step > Reach -> Step; true -> Reach end, Native)
    end.

%% Free at T: not busy, and in the free zone or, where the island has
%% none (fixtures listed near), touching none of them (the island's own
%% test). A zone is the island's with no fixture near: out of it the
%% island's test would fail on the same distance.
is_free(T, _X, _Y, _Z, _Zone, [T | _], _Island) -> false;
is_free(_T, _X, _Y, _Z, always, _Busy, _Island) -> true;
is_free(_T, X, Y, Z, {AX, AY, AZ, L2}, _Busy, _Island)
  when is_float(X), is_float(Y), is_float(Z), is_float(AX), is_float(AY), is_float(AZ), is_float(L2) ->
    DX = X - AX,
    DY = Y - AY,
    DZ = Z - AZ,
    DX * DX + DY * DY + DZ * DZ =< L2;
is_free(_T, X, Y, Z, none, _Busy, Island) -> rw_island:touches_no_fixture(Island, X, Y, Z).

%% The state appended as rw_states:append/4 appends it.
append(Bin, X, Y, Z, VX, VY, VZ, undefined, _W) ->
    <<Bin/binary, X:64/float, Y:64/float, Z:64/float, VX:64/float, VY:64/float, VZ:64/float>>;
append(Bin, X, Y, Z, VX, VY, VZ, {{QX, QY, QZ}, QW}, {WX, WY, WZ}) ->
    <<Bin/binary, X:64/float, Y:64/float, Z:64/float, VX:64/float, VY:64/float, VZ:64/float,
      QX:64/float, QY:64/float, QZ:64/float, QW:64/float, WX:64/float, WY:64/float, WZ:64/float>>.

%% A group's substeps from T: with the C loops (Contacts, the times of its
%% known contacts with the outside) the C island's up to the group's start
%% or Last, the Erlang island's where it hands over; without (false) the
%% Erlang island's.
chain(T, _States, Last, _Ctx, Island, Passed, Bins, _Native) when T >= Last ->
    {lists:reverse(Passed), Bins, Island};
chain(T, States, Last, Ctx, Island, Passed, Bins, Contacts) when is_list(Contacts) ->
    case native_island(T, Last, Ctx, Island, States, none, Contacts) of
        {T1, Next, New, none, More} when T1 > T ->
            chain(T1, Next, Last, Ctx, Island, lists:reverse(More, Passed), append_all(Bins, New), Contacts);
        _ ->
            chain_one(T, States, Last, Ctx, Island, Passed, Bins, Contacts)
    end;
chain(T, States, Last, Ctx, Island, Passed, Bins, Native) ->
    chain_one(T, States, Last, Ctx, Island, Passed, Bins, Native).

%% The C island's substeps (rw_native:island_run/10) from T up to the
%% group's start or Last, whichever comes first (the group's start is the
%% Erlang island's), with the known contacts at the times Contacts from
%% the outside and the sync points on the way; fallback where it has none
%% to take.
native_island(T, Last, {M, Dt, Base, TL, Cal}, Island, States, Acc, Contacts) ->
    Stop = case Base of
               {TB, _} when TB >= T, TB < Last -> TB;
               _ -> Last
           end,
    {_, Spheres, Fixtures} = rw_island:bodies(Island),
    Outside = [{TC, Member, Partner, Effect} || TC <- Contacts, TC >= T, TC < Stop,
                                                {Member, {{Partner, 0}, Effect}} <- rw_timeline:external(TC, TL)],
    case Stop > T of
        true -> rw_native:island_run(T, Stop, Dt, M, Spheres, Fixtures, States, Acc, syncs(T, Stop, Dt, Cal), Outside);
        false -> fallback
    end.

%% The sync points at the substeps from T (Dt apart) before Stop.
syncs(T, Stop, Dt, Cal) -> syncs(T, T, Stop, Dt, Cal).

syncs(From, T, Stop, Dt, Cal) ->
    case rw_sync:next_at(From, Cal) of
        S when is_integer(S), S < Stop, (S - T) rem Dt =:= 0 -> [S | syncs(S + 1, T, Stop, Dt, Cal)];
        S when is_integer(S), S < Stop -> syncs(S + 1, T, Stop, Dt, Cal);
        _ -> []
    end.

%% One substep of chain/8, through the island.
chain_one(T, States, Last, {M, Dt, Base, TL, Cal} = Ctx, Island, Passed, Bins, Native) ->
    {Posts, Next, Island1} =
        case Base of
            {T, BasePosts} -> {BasePosts, rw_island:advance(M, States, BasePosts), Island};
            _ -> rw_island:step(Island, States, rw_timeline:external(T, TL))
        end,
    Passed1 = case rw_sync:is_sync(T, Cal) of
                  true -> [{T, States, Posts} | Passed];
                  false -> Passed
              end,
    chain(T + Dt, Next, Last, Ctx, Island1, Passed1, add_all(1, Next, Bins, M), Native).

append_all([Bin | Bins], [New | News]) -> [<<Bin/binary, New/binary>> | append_all(Bins, News)];
append_all([], []) -> [].
