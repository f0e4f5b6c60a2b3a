/* The terms the C loops read and build: atoms, doubles in Erlang's
   binaries, the records (rw_records.h) and times. */
#ifndef RW_TERMS_H
#define RW_TERMS_H
#include <erl_nif.h>
#include <stdint.h>
#include <string.h>
#include "rw_physics.h"

extern ERL_NIF_TERM atom_always, atom_none, atom_some, atom_undefined, atom_fallback, atom_symplectic_euler,
    atom_explicit_euler, atom_verlet, atom_near, atom_fixture, atom_plane, atom_box, atom_hollow, atom_unbounded;

/* The atoms, made as the library loads. */
void rw_terms_load(ErlNifEnv *env);

/* Erlang's <<X:64/float>>: big-endian. */
static inline void put_double(unsigned char *p, double d) {
    uint64_t u;
    memcpy(&u, &d, 8);
    u = __builtin_bswap64(u);
    memcpy(p, &u, 8);
}

static inline double get_double(const unsigned char *p) {
    uint64_t u;
    double d;
    memcpy(&u, p, 8);
    u = __builtin_bswap64(u);
    memcpy(&d, &u, 8);
    return d;
}

/* An Erlang float only (enif_get_double refuses integers, as the Erlang
   code's is_float guards do): the N elements of a tuple. */
int rw_get_doubles(ErlNifEnv *env, ERL_NIF_TERM tuple, int n, double *out);
ERL_NIF_TERM rw_make_doubles(ErlNifEnv *env, const double *d, int n);
int rw_get_long(ErlNifEnv *env, ERL_NIF_TERM t, long *out);
/* #fixture{}, #model{} (without CCD), #sphere{}, #st{} (q and w with
   rotation, else undefined) */
int rw_get_fixture(ErlNifEnv *env, ERL_NIF_TERM term, struct fixture *f);
int rw_get_model(ErlNifEnv *env, ERL_NIF_TERM term, struct model *m);
int rw_get_sphere(ErlNifEnv *env, ERL_NIF_TERM term, struct sphere *s);
int rw_get_mstate(ErlNifEnv *env, ERL_NIF_TERM term, int rot, struct mstate *s);
ERL_NIF_TERM rw_make_mstate(ErlNifEnv *env, ERL_NIF_TERM st_atom, const struct mstate *s, int rot);
/* The substeps of Dtt ticks from T while T < Last, at most Max; 0 for
   times a loop could not step without overflow (the caller then falls
   back: times are never negative, nor near 2^63, in a run). */
ErlNifSInt64 rw_substeps(ErlNifSInt64 t, ErlNifSInt64 last, ErlNifSInt64 dtt, ErlNifSInt64 max);
#endif
