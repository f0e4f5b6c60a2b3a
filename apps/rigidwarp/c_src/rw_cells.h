/* The TVHT bucket's cells outside the Erlang heap (rw_cells.c), for the
   function table of rw_native.c. */
#ifndef RW_CELLS_H
#define RW_CELLS_H
#include <erl_nif.h>

int rw_cells_load(ErlNifEnv *env);
ERL_NIF_TERM rw_cells_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_cells_store(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_cells_probe(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_cells_delete(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_cells_gc(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_cells_free(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_cells_dump(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
/* rw_scan.c's scan of two bodies' packed positions for their first
   touch (rw_states:first_touch/6): 1 and the offset in *k, 0 for none,
   -1 where the Erlang code must decide. */
int rw_first_touch(const ErlNifBinary *a, ErlNifSInt64 sa, ErlNifSInt64 ia, const ErlNifBinary *b, ErlNifSInt64 sb,
                   ErlNifSInt64 ib, ErlNifSInt64 left, double sum, double margin, int has_reach, double reach,
                   ErlNifSInt64 *k);
#endif
