/*
 * The hot loops of the Time Warp engine in C, the library rw_native.erl
 * loads: its function table, and its load. Each loop does the same float
 * operations in the same order as its Erlang original, so that the
 * results are bit for bit those of the Erlang code; where the Erlang code
 * would raise badarith (a result that is not a finite double) or fail on
 * its arguments a loop answers fallback, and the caller runs the Erlang
 * code from the same point. Without the library the callers run the
 * Erlang code alone.
 *
 *   free_run/13     rw_chain's free flight of a body alone (rw_flight.c)
 *   island_run/10   rw_island:step/3 substep after substep: a contact
 *                   group, or a body alone touching a fixture
 *                   (rw_island.c)
 *   first_touch/10  rw_states:first_touch/6's scan of two bodies' packed
 *                   positions, measure/2 rw_states:seal/3's box and reach
 *                   (rw_scan.c)
 *   cells_*         a TVHT bucket's segments outside the Erlang heap
 *                   (rw_cells.c)
 *   huge_pages/0    huge pages for the VM's super carrier (rw_pages.c)
 *   layouts/0       where the C code reads the records (rw_records.h)
 *
 * The rules of the physics they share are rw_physics.c's, the terms they
 * read and build rw_terms.c's. No call takes much more than a millisecond
 * on a normal scheduler (rw_slice.h).
 */
#include "rw_cells.h"
#include "rw_nifs.h"
#include "rw_records.h"
#include "rw_slice.h"
#include "rw_terms.h"

/* Erlang's binaries hold doubles big-endian (<<X:64/float>>), which this
   library reads and writes with a byte swap: on any other host it refuses
   to load, and the Erlang code runs. (Defined on the command line, 0 shows
   the refusal on this host: rw_native_tests.) */
#ifndef RW_HOST_LITTLE_ENDIAN
#if defined(__BYTE_ORDER__) && defined(__ORDER_LITTLE_ENDIAN__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
#define RW_HOST_LITTLE_ENDIAN 1
#else
#define RW_HOST_LITTLE_ENDIAN 0
#endif
#endif

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info) {
    (void)priv;
    (void)info;
    if (!RW_HOST_LITTLE_ENDIAN) return 1;
    rw_terms_load(env);
    return rw_cells_load(env);
}

static int upgrade(ErlNifEnv *env, void **priv, void **old_priv, ERL_NIF_TERM info) {
    (void)old_priv;
    return load(env, priv, info);
}

/* A scan, short by its bound (at most 65536 substeps), its time told to
   the scheduler (free_run/13 and measure/2 tell theirs by their work). */
#define TIMED(name)                                                                            \
    static ERL_NIF_TERM timed_##name(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) { \
        ErlNifTime start = rw_now();                                                           \
        ERL_NIF_TERM result = rw_##name(env, argc, argv);                                      \
        rw_spend(env, start);                                                                  \
        return result;                                                                         \
    }
TIMED(first_touch_nif)

/* layouts(): where this library reads the Erlang records (rw_records.h). */
static ERL_NIF_TERM layouts(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    (void)argc;
    (void)argv;
    return rw_records_layouts(env);
}

static ErlNifFunc funcs[] = {
    {"nif_layouts", 0, layouts, 0},
    {"nif_free_run", 13, rw_free_run, 0},
    {"nif_first_touch", 10, timed_first_touch_nif, 0},
    {"nif_island_run", 10, rw_island_run, 0},
    {"nif_measure", 2, rw_measure, 0},
    /* (it reads a file: off the normal schedulers) */
    {"nif_huge_pages", 0, rw_huge_pages, ERL_NIF_DIRTY_JOB_IO_BOUND},
    {"nif_cells_new", 0, rw_cells_new, 0},
    {"nif_cells_store", 5, rw_cells_store, 0},
    {"nif_cells_probe", 4, rw_cells_probe, 0},
    {"nif_cells_delete", 4, rw_cells_delete, 0},
    {"nif_cells_gc", 3, rw_cells_gc, 0},
    {"nif_cells_free", 1, rw_cells_free, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"nif_cells_dump", 1, rw_cells_dump, 0},
};

ERL_NIF_INIT(rw_native, funcs, load, NULL, upgrade, NULL)
