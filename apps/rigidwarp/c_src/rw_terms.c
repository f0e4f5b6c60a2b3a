/* The terms the C loops read and build (rw_terms.h). */
#include "rw_terms.h"
#include "rw_records.h"

ERL_NIF_TERM atom_always, atom_none, atom_some, atom_undefined, atom_fallback, atom_symplectic_euler,
    atom_explicit_euler, atom_verlet, atom_near, atom_fixture, atom_plane, atom_box, atom_hollow, atom_unbounded;

void rw_terms_load(ErlNifEnv *env) {
    atom_always = enif_make_atom(env, "always");
    atom_none = enif_make_atom(env, "none");
    atom_some = enif_make_atom(env, "some");
    atom_undefined = enif_make_atom(env, "undefined");
    atom_fallback = enif_make_atom(env, "fallback");
    atom_symplectic_euler = enif_make_atom(env, "symplectic_euler");
    atom_explicit_euler = enif_make_atom(env, "explicit_euler");
    atom_verlet = enif_make_atom(env, "verlet");
    atom_near = enif_make_atom(env, "near");
    atom_fixture = enif_make_atom(env, "fixture");
    atom_plane = enif_make_atom(env, "plane");
    atom_box = enif_make_atom(env, "box");
    atom_hollow = enif_make_atom(env, "hollow");
    atom_unbounded = enif_make_atom(env, "unbounded");
}

/* An Erlang float only (enif_get_double refuses integers, as the Erlang
   code's is_float guards do). */
int rw_get_doubles(ErlNifEnv *env, ERL_NIF_TERM tuple, int n, double *out) {
    const ERL_NIF_TERM *elems;
    int arity;
    if (!enif_get_tuple(env, tuple, &arity, &elems) || arity != n) return 0;
    for (int i = 0; i < n; i++)
        if (!enif_get_double(env, elems[i], &out[i])) return 0;
    return 1;
}

ERL_NIF_TERM rw_make_doubles(ErlNifEnv *env, const double *d, int n) {
    ERL_NIF_TERM elems[7];
    for (int i = 0; i < n; i++) elems[i] = enif_make_double(env, d[i]);
    return enif_make_tuple_from_array(env, elems, n);
}

int rw_get_long(ErlNifEnv *env, ERL_NIF_TERM t, long *out) {
    ErlNifSInt64 v;
    if (!enif_get_int64(env, t, &v)) return 0;
    *out = (long)v;
    return 1;
}

/* #fixture{idx, id, shape, box}, any of rw_shape's static shapes */
int rw_get_fixture(ErlNifEnv *env, ERL_NIF_TERM term, struct fixture *f) {
    const ERL_NIF_TERM *rec, *shape;
    int arity, sa;
    if (!enif_get_tuple(env, term, &arity, &rec) || arity != FIXTURE_SIZE || !enif_is_identical(rec[0], atom_fixture) ||
        !rw_get_long(env, rec[FIXTURE_IDX], &f->idx) || !enif_get_tuple(env, rec[FIXTURE_SHAPE], &sa, &shape) || sa < 1)
        return 0;
    if (enif_is_identical(rec[FIXTURE_BOX], atom_unbounded)) f->bounded = 0;
    else if (rw_get_doubles(env, rec[FIXTURE_BOX], 6, f->box)) f->bounded = 1;
    else return 0;
    if (enif_is_identical(shape[0], atom_plane) && sa == 3) {
        f->kind = K_PLANE;
        return rw_get_doubles(env, shape[1], 3, f->a) && enif_get_double(env, shape[2], &f->off);
    }
    if (enif_is_identical(shape[0], atom_box) && sa == 4) {
        if (enif_is_identical(shape[3], atom_hollow)) f->kind = K_HOLLOW;
        else if (enif_is_identical(shape[3], enif_make_atom(env, "solid"))) f->kind = K_SOLID;
        else return 0;
        return rw_get_doubles(env, shape[1], 3, f->a) && rw_get_doubles(env, shape[2], 3, f->b);
    }
    if (enif_is_identical(shape[0], enif_make_atom(env, "cylinder")) && sa == 5) {
        f->kind = K_CYLINDER;
        return rw_get_doubles(env, shape[1], 3, f->a) && rw_get_doubles(env, shape[2], 3, f->b) &&
               enif_get_double(env, shape[3], &f->cr) && enif_get_double(env, shape[4], &f->h);
    }
    return 0;
}

/* #model{} with ccd false */
int rw_get_model(ErlNifEnv *env, ERL_NIF_TERM term, struct model *m) {
    const ERL_NIF_TERM *r;
    int arity;
    if (!enif_get_tuple(env, term, &arity, &r) || arity != MODEL_SIZE ||
        !enif_is_identical(r[0], enif_make_atom(env, "model")))
        return 0;
    if (!enif_get_double(env, r[MODEL_DT], &m->dt) || !enif_get_double(env, r[MODEL_RESTITUTION], &m->e) ||
        !enif_get_double(env, r[MODEL_REST_SPEED], &m->rest_speed) ||
        !enif_get_double(env, r[MODEL_CORRECTION], &m->beta) || !enif_get_double(env, r[MODEL_SLOP], &m->slop))
        return 0;
    m->gravity = !enif_is_identical(r[MODEL_GRAVITY], atom_undefined);
    if (m->gravity && !rw_get_doubles(env, r[MODEL_GRAVITY], 3, m->g)) return 0;
    m->friction = !enif_is_identical(r[MODEL_FRICTION], atom_undefined);
    if (m->friction && !enif_get_double(env, r[MODEL_FRICTION], &m->mu)) return 0;
    if (enif_is_identical(r[MODEL_ROTATION], enif_make_atom(env, "true"))) m->rot = 1;
    else if (enif_is_identical(r[MODEL_ROTATION], enif_make_atom(env, "false"))) m->rot = 0;
    else return 0;
    if (enif_is_identical(r[MODEL_INTEGRATOR], atom_symplectic_euler)) m->integrator = 0;
    else if (enif_is_identical(r[MODEL_INTEGRATOR], atom_explicit_euler)) m->integrator = 1;
    else if (enif_is_identical(r[MODEL_INTEGRATOR], atom_verlet)) m->integrator = 2;
    else return 0;
    return enif_is_identical(r[MODEL_CCD], enif_make_atom(env, "false"));
}

/* #sphere{idx, id, radius, mass, inv_mass, inv_inertia} */
int rw_get_sphere(ErlNifEnv *env, ERL_NIF_TERM term, struct sphere *s) {
    const ERL_NIF_TERM *r;
    int arity;
    return enif_get_tuple(env, term, &arity, &r) && arity == SPHERE_SIZE &&
           enif_is_identical(r[0], enif_make_atom(env, "sphere")) && rw_get_long(env, r[SPHERE_IDX], &s->idx) &&
           enif_get_double(env, r[SPHERE_RADIUS], &s->r) && enif_get_double(env, r[SPHERE_INV_MASS], &s->im) &&
           enif_get_double(env, r[SPHERE_INV_INERTIA], &s->ii);
}

/* #st{p, v, q, w} */
int rw_get_mstate(ErlNifEnv *env, ERL_NIF_TERM term, int rot, struct mstate *s) {
    const ERL_NIF_TERM *r, *q;
    int arity, qa;
    if (!enif_get_tuple(env, term, &arity, &r) || arity != ST_SIZE || !enif_is_identical(r[0], enif_make_atom(env, "st")) ||
        !rw_get_doubles(env, r[ST_P], 3, s->p) || !rw_get_doubles(env, r[ST_V], 3, s->v))
        return 0;
    if (!rot) return enif_is_identical(r[ST_Q], atom_undefined) && enif_is_identical(r[ST_W], atom_undefined);
    return enif_get_tuple(env, r[ST_Q], &qa, &q) && qa == 2 && rw_get_doubles(env, q[0], 3, s->q) &&
           enif_get_double(env, q[1], &s->q[3]) && rw_get_doubles(env, r[ST_W], 3, s->w);
}

ERL_NIF_TERM rw_make_mstate(ErlNifEnv *env, ERL_NIF_TERM st_atom, const struct mstate *s, int rot) {
    ERL_NIF_TERM q = atom_undefined, w = atom_undefined;
    if (rot) {
        q = enif_make_tuple2(env, rw_make_doubles(env, s->q, 3), enif_make_double(env, s->q[3]));
        w = rw_make_doubles(env, s->w, 3);
    }
    ERL_NIF_TERM r[ST_SIZE];
    r[0] = st_atom;
    r[ST_P] = rw_make_doubles(env, s->p, 3);
    r[ST_V] = rw_make_doubles(env, s->v, 3);
    r[ST_Q] = q;
    r[ST_W] = w;
    return enif_make_tuple_from_array(env, r, ST_SIZE);
}

/* The substeps of Dtt ticks from T while T < Last, at most Max; 0 for
   times a loop could not step without overflow (the caller then falls
   back: times are never negative, nor near 2^63, in a run). */
ErlNifSInt64 rw_substeps(ErlNifSInt64 t, ErlNifSInt64 last, ErlNifSInt64 dtt, ErlNifSInt64 max) {
    if (t < 0 || dtt <= 0 || t >= last || last > INT64_MAX - dtt) return 0;
    uint64_t span = (uint64_t)last - (uint64_t)t;
    uint64_t n = span / (uint64_t)dtt + (span % (uint64_t)dtt != 0);
    return n > (uint64_t)max ? max : (ErlNifSInt64)n;
}
