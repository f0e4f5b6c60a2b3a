/* A NIF call's time against its scheduler's slice. A call told the
   scheduler how long it ran, so that a process calling the C loops again
   and again yields as it would running Erlang code; the loops that could
   run long stop by the clock and hand back what is left. */
#ifndef RW_SLICE_H
#define RW_SLICE_H
#include <erl_nif.h>

/* a scheduler's time slice, about */
#define RW_SLICE_US 1000

static inline ErlNifTime rw_now(void) { return enif_monotonic_time(ERL_NIF_USEC); }

/* (0 only in a build for timing the calls by tracing them: a call that
   told its time may see its process scheduled out before the trace of its
   return, which then times what ran in between) */
#ifndef RW_REPORT_SLICE
#define RW_REPORT_SLICE 1
#endif

/* Work done at about per_ms units a millisecond, as a share of the slice:
   for the short loops, which would spend a good part of their time
   reading the clock (units of less than 1 % go uncounted). */
static inline void rw_spend_work(ErlNifEnv *env, long units, long per_ms) {
    long percent = units * 100 / per_ms;
    if (RW_REPORT_SLICE && percent > 0) (void)enif_consume_timeslice(env, percent > 100 ? 100 : (int)percent);
}

/* The time since start, as a share of the slice (calls under 10 us are
   left uncounted: a process makes thousands of them per slice). */
static inline void rw_spend(ErlNifEnv *env, ErlNifTime start) {
    ErlNifTime us = rw_now() - start;
    if (RW_REPORT_SLICE && us >= 10)
        (void)enif_consume_timeslice(env, us >= RW_SLICE_US ? 100 : (int)(us * 100 / RW_SLICE_US));
}
#endif
