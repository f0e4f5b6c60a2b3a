/* The C loops' entry points, one file each, for the function table of
   rw_native.c: free flight (rw_flight.c), the island (rw_island.c), the
   scan and measure of packed states (rw_scan.c), huge pages (rw_pages.c);
   a bucket's cells are rw_cells.h's. Each returns the atom fallback where
   the Erlang code would raise or fail on its arguments: the caller runs
   the Erlang code from the same point. */
#ifndef RW_NIFS_H
#define RW_NIFS_H
#include <erl_nif.h>

ERL_NIF_TERM rw_free_run(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_island_run(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_first_touch_nif(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_measure(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
ERL_NIF_TERM rw_huge_pages(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]);
#endif
