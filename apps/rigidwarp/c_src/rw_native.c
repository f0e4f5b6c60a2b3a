/*
 * The hot loops of the Time Warp engine in C, each the same float
 * operations in the same order as its Erlang original, so that the results
 * are bit for bit those of the Erlang code (IEEE doubles, no fused
 * multiply-add: the Makefile builds with -ffp-contract=off):
 *
 *   free_run/13     rw_chain's free flight of a body alone, while it stays
 *                   in its free zone and meets no sync point, busy substep
 *                   or the step's end;
 *   first_touch/10  rw_states:first_touch/6's scan of two bodies' packed
 *                   positions;
 *   island_run/10   rw_island:step/3 substep after substep: a contact
 *                   group, or a body alone touching a fixture;
 *   measure/2       rw_states:seal/3's box and reach of a group's states;
 *   huge_pages/0    asks Linux to back the VM's super carrier with huge
 *                   pages (rw_native:huge_pages/0);
 *   cells_*         a TVHT bucket's segments outside the Erlang heap
 *                   (rw_cells.c).
 *
 * Where the Erlang code would raise badarith (a result that is not a
 * finite double) or fail on its arguments these return the atom fallback,
 * and the caller runs the Erlang code from the same point, which does what
 * it does. rw_native.erl loads this library; without it the callers run
 * the Erlang code alone.
 */
/* (madvise's MADV_HUGEPAGE beside -std=c99) */
#define _DEFAULT_SOURCE
#include <erl_nif.h>
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#ifdef __linux__
#include <sys/mman.h>
#endif
#include "rw_cells.h"
#include "rw_records.h"
#include "rw_slice.h"

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

static ERL_NIF_TERM atom_always, atom_none, atom_some, atom_undefined, atom_fallback, atom_symplectic_euler,
    atom_explicit_euler, atom_verlet, atom_near, atom_fixture, atom_plane, atom_box, atom_hollow, atom_unbounded;

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info) {
    (void)priv;
    (void)info;
    if (!RW_HOST_LITTLE_ENDIAN) return 1;
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
    return rw_cells_load(env);
}

static int upgrade(ErlNifEnv *env, void **priv, void **old_priv, ERL_NIF_TERM info) {
    (void)old_priv;
    return load(env, priv, info);
}

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
   code's is_float guards do). */
static int get_doubles(ErlNifEnv *env, ERL_NIF_TERM tuple, int n, double *out) {
    const ERL_NIF_TERM *elems;
    int arity;
    if (!enif_get_tuple(env, tuple, &arity, &elems) || arity != n) return 0;
    for (int i = 0; i < n; i++)
        if (!enif_get_double(env, elems[i], &out[i])) return 0;
    return 1;
}

static ERL_NIF_TERM make_doubles(ErlNifEnv *env, const double *d, int n) {
    ERL_NIF_TERM elems[7];
    for (int i = 0; i < n; i++) elems[i] = enif_make_double(env, d[i]);
    return enif_make_tuple_from_array(env, elems, n);
}

/* A body's box and reach (rw_states:pack/4's measure) grown by its next
   position, Step from the one before. */
static inline void grow(double *box, double *reach, double x, double y, double z, double step) {
    if (x < box[0]) box[0] = x;
    if (y < box[1]) box[1] = y;
    if (z < box[2]) box[2] = z;
    if (x > box[3]) box[3] = x;
    if (y > box[4]) box[4] = y;
    if (z > box[5]) box[5] = z;
    if (step > *reach) *reach = step;
}

/* A call runs for microseconds, well within a scheduler's time slice:
   free_run/13 takes at most this many substeps (the caller calls again
   for more), first_touch/10 leaves longer scans to the Erlang code. */
#define MAX_SUBSTEPS 4096
#define MAX_SCAN 65536

/* (a result Erlang would refuse: infinite or not a number) */
#define CHECK(v) (bad |= !isfinite(v))

/* The substeps of Dtt ticks from T while T < Last, at most Max; 0 for
   times a loop could not step without overflow (the caller then falls
   back: times are never negative, nor near 2^63, in a run). */
static ErlNifSInt64 substeps(ErlNifSInt64 t, ErlNifSInt64 last, ErlNifSInt64 dtt, ErlNifSInt64 max) {
    if (t < 0 || dtt <= 0 || t >= last || last > INT64_MAX - dtt) return 0;
    uint64_t span = (uint64_t)last - (uint64_t)t;
    uint64_t n = span / (uint64_t)dtt + (span % (uint64_t)dtt != 0);
    return n > (uint64_t)max ? max : (ErlNifSInt64)n;
}

/* A fixture: its shape and its bounding box. */
enum kind { K_PLANE, K_HOLLOW, K_SOLID, K_CYLINDER };

struct fixture {
    long idx;
    int bounded;
    double box[6];
    enum kind kind;
    double a[3], b[3]; /* plane: normal; boxes: centre, half extents; cylinder: centre, axis */
    double off, cr, h; /* plane offset; cylinder radius and half length */
};

#define MAX_NEAR 16

static int get_long(ErlNifEnv *env, ERL_NIF_TERM t, long *out) {
    ErlNifSInt64 v;
    if (!enif_get_int64(env, t, &v)) return 0;
    *out = (long)v;
    return 1;
}

/* #fixture{idx, id, shape, box}, any of rw_shape's static shapes */
static int get_fixture(ErlNifEnv *env, ERL_NIF_TERM term, struct fixture *f) {
    const ERL_NIF_TERM *rec, *shape;
    int arity, sa;
    if (!enif_get_tuple(env, term, &arity, &rec) || arity != FIXTURE_SIZE || !enif_is_identical(rec[0], atom_fixture) ||
        !get_long(env, rec[FIXTURE_IDX], &f->idx) || !enif_get_tuple(env, rec[FIXTURE_SHAPE], &sa, &shape) || sa < 1)
        return 0;
    if (enif_is_identical(rec[FIXTURE_BOX], atom_unbounded)) f->bounded = 0;
    else if (get_doubles(env, rec[FIXTURE_BOX], 6, f->box)) f->bounded = 1;
    else return 0;
    if (enif_is_identical(shape[0], atom_plane) && sa == 3) {
        f->kind = K_PLANE;
        return get_doubles(env, shape[1], 3, f->a) && enif_get_double(env, shape[2], &f->off);
    }
    if (enif_is_identical(shape[0], atom_box) && sa == 4) {
        if (enif_is_identical(shape[3], atom_hollow)) f->kind = K_HOLLOW;
        else if (enif_is_identical(shape[3], enif_make_atom(env, "solid"))) f->kind = K_SOLID;
        else return 0;
        return get_doubles(env, shape[1], 3, f->a) && get_doubles(env, shape[2], 3, f->b);
    }
    if (enif_is_identical(shape[0], enif_make_atom(env, "cylinder")) && sa == 5) {
        f->kind = K_CYLINDER;
        return get_doubles(env, shape[1], 3, f->a) && get_doubles(env, shape[2], 3, f->b) &&
               enif_get_double(env, shape[3], &f->cr) && enif_get_double(env, shape[4], &f->h);
    }
    return 0;
}

/*
 * Does a sphere of radius r at (x, y, z) certainly touch none of the
 * fixtures, by rw_narrow:fixture/3's own operations? 1: none touched; 0:
 * one may be (a contact, or a shape whose test is left to the Erlang
 * code). Sets *bad where an operation gives no finite double.
 */
static int touches_none(const struct fixture *fs, int n, double x, double y, double z, double r, int *bad_out) {
    int bad = 0;
    for (int i = 0; i < n; i++) {
        const struct fixture *f = &fs[i];
        if (f->bounded) {
            /* X + R < X0 orelse X - R > X1 orelse ... : rejected by the box */
            double c[6] = {x + r, x - r, y + r, y - r, z + r, z - r};
            int rejected = 0;
            for (int k = 0; k < 6 && !rejected; k++) {
                CHECK(c[k]);
                rejected = (k % 2 == 0) ? c[k] < f->box[k / 2] : c[k] > f->box[3 + k / 2];
            }
            if (bad) break;
            if (rejected) continue;
        }
        if (f->kind == K_PLANE) {
            /* Depth = R - (vdot(N, P) - Off), a contact when above 0.0 */
            double d1 = f->a[0] * x, d2 = f->a[1] * y, d3 = f->a[2] * z;
            double dot = d1 + d2 + d3, rel = dot - f->off, depth = r - rel;
            CHECK(d1); CHECK(d2); CHECK(d3); CHECK(d1 + d2); CHECK(dot); CHECK(rel); CHECK(depth);
            if (bad) break;
            if (depth > 0.0) { *bad_out = 0; return 0; }
        } else if (f->kind == K_HOLLOW) {
            /* the six depths rw_narrow tests before computing any wall */
            double cx = f->a[0], cy = f->a[1], cz = f->a[2], ex = f->b[0], ey = f->b[1], ez = f->b[2];
            double lo[3] = {cx - ex, cy - ey, cz - ez}, hi[3] = {cx + ex, cy + ey, cz + ez}, p[3] = {x, y, z};
            for (int k = 0; k < 3; k++) {
                double in_lo = p[k] - lo[k], d_lo = r - in_lo, in_hi = -p[k] + hi[k], d_hi = r - in_hi;
                CHECK(lo[k]); CHECK(hi[k]); CHECK(in_lo); CHECK(d_lo); CHECK(in_hi); CHECK(d_hi);
                if (bad) break;
                if (d_lo > 0.0 || d_hi > 0.0) { *bad_out = 0; return 0; }
            }
            if (bad) break;
        } else {
            *bad_out = 0;
            return 0;
        }
    }
    *bad_out = bad;
    return !bad;
}

/*
 * free_run(T, Last, DtT, Dt, Sync, Busy, Zone, Gravity, Integrator,
 *          {X, Y, Z, VX, VY, VZ}, Q, W, {First, {X0, Y0, Z0, X1, Y1, Z1}, Reach})
 *
 * Q, W: the orientation {{QX, QY, QZ}, QW} and spin {WX, WY, WZ}, or both
 * undefined (no rotation).
 * Sync, Busy: the next sync point and busy substep (none: no such).
 * Zone: always or {AX, AY, AZ, L2} (rw_island:free_zone/1), or
 * {near, AX, AY, AZ, Limit, R, Fixtures} (rw_island:near_zone/1: free
 * within Limit of the anchor where touches_no_fixture/4 finds no fixture
 * touched).
 * Gravity: undefined or {GX, GY, GZ}.
 *
 * Steps substep by substep while T < Last, T is neither Sync nor Busy and
 * the body is in its zone, as rw_chain:flight/26 does, at most
 * MAX_SUBSTEPS, and returns
 *   {T, {X, Y, Z, VX, VY, VZ}, Q, States, {First, Box, Reach}}
 * with States the states appended (rw_states' layout), or fallback.
 */
static ERL_NIF_TERM free_run(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    ErlNifSInt64 t, last, dtt, sync = -1, busy = -1;
    double dt, zone[4] = {0, 0, 0, 0}, g[3] = {0, 0, 0}, s[6], q[4] = {0, 0, 0, 0}, w[3] = {0, 0, 0}, box[6], reach;
    double radius = 0.0;
    int always, gravity, integrator = 0, rotation, spinning = 0, first, near = 0, bad = 0;
    struct fixture fixtures[MAX_NEAR];
    unsigned nfixtures = 0;
    const ERL_NIF_TERM *elems;
    int arity;
    (void)argc;

    if (!enif_get_int64(env, argv[0], &t) || !enif_get_int64(env, argv[1], &last) ||
        !enif_get_int64(env, argv[2], &dtt) || dtt <= 0 || !enif_get_double(env, argv[3], &dt))
        return atom_fallback;
    if (!enif_get_int64(env, argv[4], &sync) && !enif_is_identical(argv[4], atom_none)) return atom_fallback;
    if (!enif_get_int64(env, argv[5], &busy) && !enif_is_identical(argv[5], atom_none)) return atom_fallback;
    always = enif_is_identical(argv[6], atom_always);
    if (!always && !get_doubles(env, argv[6], 4, zone)) {
        ERL_NIF_TERM list, head;
        double limit;
        if (!enif_get_tuple(env, argv[6], &arity, &elems) || arity != 7 || !enif_is_identical(elems[0], atom_near) ||
            !enif_get_double(env, elems[1], &zone[0]) || !enif_get_double(env, elems[2], &zone[1]) ||
            !enif_get_double(env, elems[3], &zone[2]) || !enif_get_double(env, elems[4], &limit) ||
            !enif_get_double(env, elems[5], &radius) || !enif_get_list_length(env, elems[6], &nfixtures) ||
            nfixtures > MAX_NEAR)
            return atom_fallback;
        /* (touches_no_fixture/4 squares Limit) */
        zone[3] = limit * limit;
        CHECK(zone[3]);
        if (bad) return atom_fallback;
        list = elems[6];
        for (unsigned i = 0; i < nfixtures; i++) {
            if (!enif_get_list_cell(env, list, &head, &list) || !get_fixture(env, head, &fixtures[i]))
                return atom_fallback;
        }
        near = 1;
    }
    gravity = !enif_is_identical(argv[7], atom_undefined);
    if (gravity) {
        if (!get_doubles(env, argv[7], 3, g)) return atom_fallback;
        if (enif_is_identical(argv[8], atom_symplectic_euler)) integrator = 0;
        else if (enif_is_identical(argv[8], atom_explicit_euler)) integrator = 1;
        else if (enif_is_identical(argv[8], atom_verlet)) integrator = 2;
        else return atom_fallback;
    }
    if (!get_doubles(env, argv[9], 6, s)) return atom_fallback;
    rotation = !enif_is_identical(argv[10], atom_undefined);
    if (rotation != !enif_is_identical(argv[11], atom_undefined)) return atom_fallback;
    if (rotation) {
        if (!enif_get_tuple(env, argv[10], &arity, &elems) || arity != 2 || !get_doubles(env, elems[0], 3, q) ||
            !enif_get_double(env, elems[1], &q[3]) || !get_doubles(env, argv[11], 3, w))
            return atom_fallback;
        /* rw_quat:integrate/3: no spin (-0.0 too) leaves the orientation */
        spinning = !(w[0] == 0.0 && w[1] == 0.0 && w[2] == 0.0);
    }
    if (!enif_get_tuple(env, argv[12], &arity, &elems) || arity != 3 || !get_doubles(env, elems[1], 6, box) ||
        !enif_get_double(env, elems[2], &reach))
        return atom_fallback;
    if (enif_is_identical(elems[0], atom_some)) first = 1;
    else if (enif_is_identical(elems[0], atom_none)) first = 0;
    else return atom_fallback;

    if (t < 0 || last > INT64_MAX - dtt) return atom_fallback;
    ErlNifSInt64 max = substeps(t, last, dtt, MAX_SUBSTEPS);
    size_t record = rotation ? 13 * 8 : 6 * 8;
    ErlNifBinary states;
    if (!enif_alloc_binary(max * record, &states)) return atom_fallback;
    unsigned char *out = states.data;
    double x = s[0], y = s[1], z = s[2], vx = s[3], vy = s[4], vz = s[5];

    ErlNifSInt64 n = 0;
    while (n < max && t < last && t != sync && t != busy) {
        if (!always) {
            double dx = x - zone[0], dy = y - zone[1], dz = z - zone[2];
            double d2 = dx * dx + dy * dy + dz * dz;
            CHECK(dx); CHECK(dy); CHECK(dz); CHECK(dx * dx); CHECK(dy * dy); CHECK(dz * dz); CHECK(d2);
            if (bad) break;
            if (!(d2 <= zone[3])) break;
            if (near && !touches_none(fixtures, (int)nfixtures, x, y, z, radius, &bad)) break;
        }
        double nx, ny, nz, nvx, nvy, nvz;
        if (!gravity) {
            nx = x + vx * dt; ny = y + vy * dt; nz = z + vz * dt;
            CHECK(vx * dt); CHECK(vy * dt); CHECK(vz * dt);
            nvx = vx; nvy = vy; nvz = vz;
        } else {
            double vxg = vx + g[0] * dt, vyg = vy + g[1] * dt, vzg = vz + g[2] * dt;
            CHECK(g[0] * dt); CHECK(g[1] * dt); CHECK(g[2] * dt); CHECK(vxg); CHECK(vyg); CHECK(vzg);
            if (integrator == 0) {
                nx = x + vxg * dt; ny = y + vyg * dt; nz = z + vzg * dt;
                CHECK(vxg * dt); CHECK(vyg * dt); CHECK(vzg * dt);
            } else if (integrator == 1) {
                nx = x + vx * dt; ny = y + vy * dt; nz = z + vz * dt;
                CHECK(vx * dt); CHECK(vy * dt); CHECK(vz * dt);
            } else {
                double h = 0.5 * dt * dt;
                double px = x + vx * dt, py = y + vy * dt, pz = z + vz * dt;
                CHECK(0.5 * dt); CHECK(h); CHECK(vx * dt); CHECK(vy * dt); CHECK(vz * dt);
                CHECK(px); CHECK(py); CHECK(pz); CHECK(g[0] * h); CHECK(g[1] * h); CHECK(g[2] * h);
                nx = px + g[0] * h; ny = py + g[1] * h; nz = pz + g[2] * h;
            }
            nvx = vxg; nvy = vyg; nvz = vzg;
        }
        CHECK(nx); CHECK(ny); CHECK(nz);
        double nq[4] = {q[0], q[1], q[2], q[3]};
        if (spinning) {
            /* rw_quat:integrate/3, operation for operation */
            double X = q[0], Y = q[1], Z = q[2], W = q[3], ox = w[0], oy = w[1], oz = w[2];
            double dX = (X * 0.0 + ox * W) + (oy * Z - oz * Y);
            double dY = (Y * 0.0 + oy * W) + (oz * X - ox * Z);
            double dZ = (Z * 0.0 + oz * W) + (ox * Y - oy * X);
            double dW = 0.0 * W - (ox * X + oy * Y + oz * Z);
            CHECK(ox * W); CHECK(oy * Z); CHECK(oz * Y); CHECK(oy * W); CHECK(oz * X); CHECK(ox * Z);
            CHECK(oz * W); CHECK(ox * Y); CHECK(oy * X); CHECK(ox * X); CHECK(oy * Y); CHECK(oz * Z);
            CHECK(oy * Z - oz * Y); CHECK(oz * X - ox * Z); CHECK(ox * Y - oy * X);
            CHECK(ox * X + oy * Y); CHECK(ox * X + oy * Y + oz * Z);
            CHECK(dX); CHECK(dY); CHECK(dZ); CHECK(dW);
            double h = 0.5 * dt;
            double X1 = X + dX * h, Y1 = Y + dY * h, Z1 = Z + dZ * h, W1 = W + dW * h;
            CHECK(h); CHECK(dX * h); CHECK(dY * h); CHECK(dZ * h); CHECK(dW * h);
            CHECK(X1); CHECK(Y1); CHECK(Z1); CHECK(W1);
            double l2 = X1 * X1 + Y1 * Y1 + Z1 * Z1 + W1 * W1;
            CHECK(X1 * X1); CHECK(Y1 * Y1); CHECK(Z1 * Z1); CHECK(W1 * W1);
            CHECK(X1 * X1 + Y1 * Y1); CHECK(X1 * X1 + Y1 * Y1 + Z1 * Z1); CHECK(l2);
            if (bad) break;
            double l = sqrt(l2);
            if (l > 0.0) {
                double sc = 1.0 / l;
                CHECK(sc);
                nq[0] = X1 * sc; nq[1] = Y1 * sc; nq[2] = Z1 * sc; nq[3] = W1 / l;
            } else {
                nq[0] = X1; nq[1] = Y1; nq[2] = Z1; nq[3] = W1;
            }
            CHECK(nq[0]); CHECK(nq[1]); CHECK(nq[2]); CHECK(nq[3]);
        }
        double step = 0.0;
        if (first) {
            step = fabs(nx - x) + fabs(ny - y) + fabs(nz - z);
            CHECK(nx - x); CHECK(ny - y); CHECK(nz - z); CHECK(fabs(nx - x) + fabs(ny - y)); CHECK(step);
        }
        if (bad) break;

        put_double(out, nx); put_double(out + 8, ny); put_double(out + 16, nz);
        put_double(out + 24, nvx); put_double(out + 32, nvy); put_double(out + 40, nvz);
        if (rotation) {
            for (int i = 0; i < 4; i++) put_double(out + 48 + 8 * i, nq[i]);
            for (int i = 0; i < 3; i++) put_double(out + 80 + 8 * i, w[i]);
        }
        out += record;
        n++;
        if (!first) {
            /* the first state: the box is its position, the reach 0 */
            first = 1;
            box[0] = nx; box[1] = ny; box[2] = nz; box[3] = nx; box[4] = ny; box[5] = nz;
            reach = 0.0;
        } else {
            grow(box, &reach, nx, ny, nz, step);
        }
        x = nx; y = ny; z = nz; vx = nvx; vy = nvy; vz = nvz;
        memcpy(q, nq, sizeof q);
        t += dtt;
    }
    if (bad || !enif_realloc_binary(&states, n * record)) {
        enif_release_binary(&states);
        return atom_fallback;
    }
    double pv[6] = {x, y, z, vx, vy, vz};
    ERL_NIF_TERM orientation = rotation
        ? (spinning ? enif_make_tuple2(env, make_doubles(env, q, 3), enif_make_double(env, q[3])) : argv[10])
        : atom_undefined;
    return enif_make_tuple5(env, enif_make_int64(env, t), make_doubles(env, pv, 6), orientation,
                            enif_make_binary(env, &states),
                            enif_make_tuple3(env, first ? atom_some : atom_none, make_doubles(env, box, 6),
                                             enif_make_double(env, reach)));
}

/*
 * first_touch(BinA, SizeA, IA, BinB, SizeB, IB, Left, Sum, Margin, Reach)
 * -> K | none | fallback, as rw_states:touch/10 with Reach a float or
 * undefined.
 */
/* The scan of first_touch/10 (and of the TVHT's C cells, rw_cells.c):
   1 and the offset in *k, 0 for none, -1 for fallback. */
int rw_first_touch(const ErlNifBinary *a, ErlNifSInt64 sa, ErlNifSInt64 ia, const ErlNifBinary *b, ErlNifSInt64 sb,
                   ErlNifSInt64 ib, ErlNifSInt64 left, double sum, double margin, int has_reach, double reach,
                   ErlNifSInt64 *k_out) {
    ErlNifSInt64 k = 0;
    if (sa < 24 || sb < 24 || left < 0 || left > MAX_SCAN) return -1;
    /* the records read: from the ia-th and ib-th on, each within its
       binary (no product of the arguments is formed that could wrap) */
    if ((uint64_t)sa > a->size || (uint64_t)sb > b->size) return -1;
    uint64_t ia_max = (a->size - (uint64_t)sa) / (uint64_t)sa + 1, ib_max = (b->size - (uint64_t)sb) / (uint64_t)sb + 1;
    int bad = 0;
    double sum2 = sum * sum;
    CHECK(sum2);
    if (bad) return -1;
    for (;;) {
        if (ia < 1 || ib < 1 || (uint64_t)ia > ia_max || (uint64_t)ib > ib_max) return -1;
        const unsigned char *pa = a->data + (ia - 1) * sa, *pb = b->data + (ib - 1) * sb;
        double dx = get_double(pb) - get_double(pa), dy = get_double(pb + 8) - get_double(pa + 8),
               dz = get_double(pb + 16) - get_double(pa + 16);
        double d2 = dx * dx + dy * dy + dz * dz;
        CHECK(dx); CHECK(dy); CHECK(dz); CHECK(dx * dx); CHECK(dy * dy); CHECK(dz * dz); CHECK(dx * dx + dy * dy);
        CHECK(d2);
        if (bad) return -1;
        if (d2 < sum2) {
            *k_out = k;
            return 1;
        }
        if (left == 0) return 0;
        double gap = sqrt(d2) - sum - margin;
        CHECK(sqrt(d2) - sum); CHECK(gap);
        if (bad) return -1;
        ErlNifSInt64 skip;
        if (!has_reach || gap <= reach) {
            skip = 0;
        } else {
            double span = (double)left * reach;
            CHECK(span);
            if (bad) return -1;
            if (gap >= span) {
                skip = left;
            } else {
                double ratio = gap / reach;
                CHECK(ratio);
                if (bad) return -1;
                skip = (ErlNifSInt64)ratio;
            }
        }
        if (skip >= left) return 0;
        ia += skip + 1;
        ib += skip + 1;
        left -= skip + 1;
        k += skip + 1;
    }
}

static ERL_NIF_TERM first_touch(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    ErlNifBinary a, b;
    ErlNifSInt64 sa, sb, ia, ib, left, k = 0;
    double sum, margin, reach = 0.0;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &a) || !enif_get_int64(env, argv[1], &sa) ||
        !enif_get_int64(env, argv[2], &ia) || !enif_inspect_binary(env, argv[3], &b) ||
        !enif_get_int64(env, argv[4], &sb) || !enif_get_int64(env, argv[5], &ib) ||
        !enif_get_int64(env, argv[6], &left) || !enif_get_double(env, argv[7], &sum) ||
        !enif_get_double(env, argv[8], &margin))
        return atom_fallback;
    int has_reach = enif_get_double(env, argv[9], &reach);
    if (!has_reach && !enif_is_identical(argv[9], atom_undefined)) return atom_fallback;
    switch (rw_first_touch(&a, sa, ia, &b, sb, ib, left, sum, margin, has_reach, reach, &k)) {
    case 1: return enif_make_int64(env, k);
    case 0: return atom_none;
    default: return atom_fallback;
    }
}

/*
 * The island: a contact group's substeps (rw_island:step/3 without CCD
 * and without contacts from outside), each member's fixture contacts in
 * turn, the contacts among members, the effects summed in canonical order
 * and integrated.
 *
 * Where rw_native's other loops check each intermediate result, this one
 * reads the floating-point exception flags: its inputs are finite (Erlang
 * floats), so the first result that is not finite raises overflow,
 * division by zero or invalid, which is where the Erlang code raises
 * badarith. A substep that raises one is dropped, and the Erlang code
 * takes it.
 */
#include <fenv.h>
#include <stdlib.h>

#define BAD_FLAGS (FE_OVERFLOW | FE_DIVBYZERO | FE_INVALID)
/* A call on a normal scheduler: at most this many member-substeps (the
   states it returns are allocated for them) and, after its first substep,
   none begun past half a slice (a member-substep takes 0.2-1 us in a
   resting pile with friction and rotation). */
#define MAX_ISLAND_WORK 4096
#define ISLAND_BUDGET_US (RW_SLICE_US / 2)
/* A group of this many members or more steps on a dirty CPU scheduler:
   a substep of its own would take a good part of a slice, and each call
   reads and builds every member's terms; there a call takes more
   substeps, up to a few milliseconds, so that it reads and builds them
   less often. */
#define DIRTY_MEMBERS 128
#define MAX_ISLAND_WORK_DIRTY 32768
#define ISLAND_BUDGET_DIRTY_US (5 * RW_SLICE_US)

struct sphere { long idx; double r, im, ii; };

struct model {
    double dt, g[3], e, mu, rest_speed, beta, slop;
    int gravity, friction, rot, integrator;
};

struct contact { double n[3], depth; };

/* An effect under its key {idx, feature}. */
struct effect {
    long key, feature;
    double dv[3], dw[3], du[3];
};

/* A growable array of effects. */
struct effects { struct effect *e; size_t n, cap; };

static struct effect *effects_add(struct effects *es) {
    if (es->n == es->cap) {
        size_t cap = es->cap ? 2 * es->cap : 64;
        struct effect *e = enif_realloc(es->e, cap * sizeof *e);
        if (!e) return NULL;
        es->e = e;
        es->cap = cap;
    }
    return &es->e[es->n++];
}

/* Erlang's min/2 and max/2 (equal terms: the first), abs/1 (-0.0 stays). */
static inline double emin(double a, double b) { return a <= b ? a : b; }
static inline double emax(double a, double b) { return a >= b ? a : b; }
static inline double eabs(double a) { return a < 0.0 ? -a : a; }
static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static inline double len2_3(const double *a) { return a[0] * a[0] + a[1] * a[1] + a[2] * a[2]; }

/* #model{} with ccd false */
static int get_model(ErlNifEnv *env, ERL_NIF_TERM term, struct model *m) {
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
    if (m->gravity && !get_doubles(env, r[MODEL_GRAVITY], 3, m->g)) return 0;
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
static int get_sphere(ErlNifEnv *env, ERL_NIF_TERM term, struct sphere *s) {
    const ERL_NIF_TERM *r;
    int arity;
    return enif_get_tuple(env, term, &arity, &r) && arity == SPHERE_SIZE &&
           enif_is_identical(r[0], enif_make_atom(env, "sphere")) && get_long(env, r[SPHERE_IDX], &s->idx) &&
           enif_get_double(env, r[SPHERE_RADIUS], &s->r) && enif_get_double(env, r[SPHERE_INV_MASS], &s->im) &&
           enif_get_double(env, r[SPHERE_INV_INERTIA], &s->ii);
}

/* rw_narrow:point_contact/3 */
static int point_contact(const double *p, double r, const double *closest, struct contact *c) {
    double d[3] = {closest[0] - p[0], closest[1] - p[1], closest[2] - p[2]};
    double l2 = len2_3(d);
    if (!(l2 < r * r)) return 0;
    double l = sqrt(l2), s = 1.0 / l;
    c->n[0] = d[0] * s; c->n[1] = d[1] * s; c->n[2] = d[2] * s;
    c->depth = r - l;
    return 1;
}

static void unit_axis(int axis, double s, double *out) {
    out[0] = axis == 0 ? s : 0.0;
    out[1] = axis == 1 ? s : 0.0;
    out[2] = axis == 2 ? s : 0.0;
}

/*
 * rw_narrow:fixture/3: the contacts of a sphere of radius r at p with f,
 * in feature order, into c (up to 6) with their features; returns how
 * many.
 */
static int fixture_contacts(const double *p, double r, const struct fixture *f, struct contact *c, int *feature) {
    if (f->bounded && (p[0] + r < f->box[0] || p[0] - r > f->box[3] || p[1] + r < f->box[1] || p[1] - r > f->box[4] ||
                       p[2] + r < f->box[2] || p[2] - r > f->box[5]))
        return 0;
    switch (f->kind) {
    case K_PLANE: {
        double depth = r - (dot3(f->a, p) - f->off);
        if (!(depth > 0.0)) return 0;
        c[0].n[0] = -f->a[0]; c[0].n[1] = -f->a[1]; c[0].n[2] = -f->a[2];
        c[0].depth = depth;
        feature[0] = 0;
        return 1;
    }
    case K_HOLLOW: {
        const double *C = f->a, *E = f->b;
        if (!(r - (p[0] - (C[0] - E[0])) > 0.0 || r - (-p[0] + (C[0] + E[0])) > 0.0 ||
              r - (p[1] - (C[1] - E[1])) > 0.0 || r - (-p[1] + (C[1] + E[1])) > 0.0 ||
              r - (p[2] - (C[2] - E[2])) > 0.0 || r - (-p[2] + (C[2] + E[2])) > 0.0))
            return 0;
        /* walls/4: each wall's plane, its normal into the box */
        int k = 0;
        for (int w = 0; w < 6; w++) {
            int axis = w / 2;
            double n[3], off;
            if (w % 2 == 0) { unit_axis(axis, 1.0, n); off = C[axis] - E[axis]; }
            else { unit_axis(axis, -1.0, n); off = -(C[axis] + E[axis]); }
            double depth = r - (dot3(n, p) - off);
            if (depth > 0.0) {
                c[k].n[0] = -n[0]; c[k].n[1] = -n[1]; c[k].n[2] = -n[2];
                c[k].depth = depth;
                feature[k++] = w;
            }
        }
        return k;
    }
    case K_SOLID: {
        const double *C = f->a, *E = f->b;
        double closest[3];
        for (int i = 0; i < 3; i++) closest[i] = emax(C[i] - E[i], emin(C[i] + E[i], p[i]));
        feature[0] = 0;
        if (closest[0] == p[0] && closest[1] == p[1] && closest[2] == p[2]) {
            /* centre inside: leave through the nearest face */
            double rel[3] = {p[0] - C[0], p[1] - C[1], p[2] - C[2]};
            double slack[3];
            for (int i = 0; i < 3; i++) slack[i] = E[i] - eabs(rel[i]);
            int best = 0;
            for (int i = 1; i < 3; i++)
                if (slack[i] < slack[best]) best = i;
            unit_axis(best, rel[best] >= 0.0 ? -1.0 : 1.0, c[0].n);
            c[0].depth = r + slack[best];
            return 1;
        }
        return point_contact(p, r, closest, &c[0]);
    }
    case K_CYLINDER: {
        const double *C = f->a, *axis = f->b;
        double cr = f->cr, h = f->h;
        double rel[3] = {p[0] - C[0], p[1] - C[1], p[2] - C[2]};
        double h0 = dot3(rel, axis), mh0 = -h0;
        double radial[3] = {rel[0] + axis[0] * mh0, rel[1] + axis[1] * mh0, rel[2] + axis[2] * mh0};
        double rl = sqrt(len2_3(radial));
        feature[0] = 0;
        if (eabs(h0) <= h && rl <= cr) {
            double side = cr - rl, cap = h - eabs(h0);
            if (side < cap) {
                if (rl > 1.0e-12 * emax(sqrt(len2_3(rel)), cr)) {
                    double s = -1.0 / rl;
                    c[0].n[0] = radial[0] * s; c[0].n[1] = radial[1] * s; c[0].n[2] = radial[2] * s;
                } else {
                    /* any_perpendicular/1 */
                    double other[3] = {0.0, 0.0, 0.0};
                    if (eabs(axis[0]) < 0.9) other[0] = 1.0; else other[1] = 1.0;
                    double x[3] = {axis[1] * other[2] - axis[2] * other[1], axis[2] * other[0] - axis[0] * other[2],
                                   axis[0] * other[1] - axis[1] * other[0]};
                    double l = sqrt(len2_3(x));
                    if (l > 0.0) {
                        double s = 1.0 / l;
                        x[0] = x[0] * s; x[1] = x[1] * s; x[2] = x[2] * s;
                    }
                    memcpy(c[0].n, x, sizeof x);
                }
                c[0].depth = r + side;
            } else {
                double s = h0 >= 0.0 ? -1.0 : 1.0;
                c[0].n[0] = axis[0] * s; c[0].n[1] = axis[1] * s; c[0].n[2] = axis[2] * s;
                c[0].depth = r + cap;
            }
            return 1;
        }
        if (rl > (cr + r) * (1.0 + 1.0e-9) || eabs(h0) > (h + r) * (1.0 + 1.0e-9)) return 0;
        double hc = emax(-h, emin(h, h0));
        double radc[3];
        if (rl > cr) {
            double s = cr / rl;
            radc[0] = radial[0] * s; radc[1] = radial[1] * s; radc[2] = radial[2] * s;
        } else {
            memcpy(radc, radial, sizeof radc);
        }
        double closest[3];
        for (int i = 0; i < 3; i++) closest[i] = (C[i] + axis[i] * hc) + radc[i];
        return point_contact(p, r, closest, &c[0]);
    }
    }
    return 0;
}

/*
 * rw_response:normal_friction/11: the impulse j on A and the
 * pseudo-impulse *ub (*has_ub: whether anything penetrates).
 */
static void normal_friction(const struct model *m, const double *rel, const double *n, double k, double krot,
                            double depth, double *j, double *ub, int *has_ub) {
    double vn = rel[0] * n[0] + rel[1] * n[1] + rel[2] * n[2];
    double jn = 0.0;
    if (vn < 0.0) {
        double bounce = -vn > m->rest_speed ? m->e : 0.0;
        jn = -(1.0 + bounce) * vn / k;
    }
    double pen = depth - m->slop;
    *has_ub = pen > 0.0;
    if (*has_ub) *ub = m->beta * pen / m->dt / k;
    double mjn = -jn;
    j[0] = n[0] * mjn; j[1] = n[1] * mjn; j[2] = n[2] * mjn;
    if (m->friction && jn > 0.0) {
        double mvn = -vn;
        double t[3] = {rel[0] + n[0] * mvn, rel[1] + n[1] * mvn, rel[2] + n[2] * mvn};
        double lt = sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
        if (lt > 1.0e-12) {
            double kt = m->rot ? k + krot : k;
            double s = emin(lt / kt, m->mu * jn) / lt;
            j[0] = j[0] + t[0] * s; j[1] = j[1] + t[1] * s; j[2] = j[2] + t[2] * s;
        }
    }
}

/* rw_response:side/11 without a time of impact (toi 0.0) */
static void side(const double *j, const double *arm, double im, double arm_scale, int has_ub, double ub,
                 const double *n, int rot, struct effect *e) {
    e->dv[0] = j[0] * im; e->dv[1] = j[1] * im; e->dv[2] = j[2] * im;
    if (rot) { e->dw[0] = arm[0] * arm_scale; e->dw[1] = arm[1] * arm_scale; e->dw[2] = arm[2] * arm_scale; }
    if (has_ub) {
        double s = -ub * im;
        e->du[0] = n[0] * s; e->du[1] = n[1] * s; e->du[2] = n[2] * s;
    } else {
        e->du[0] = 0.0; e->du[1] = 0.0; e->du[2] = 0.0;
    }
}

static void arm_of(const double *n, const double *j, double *arm) {
    arm[0] = n[1] * j[2] - n[2] * j[1];
    arm[1] = n[2] * j[0] - n[0] * j[2];
    arm[2] = n[0] * j[1] - n[1] * j[0];
}

/* rw_response:fixture/4 (toi 0.0) */
static void fixture_response(const struct model *m, const struct sphere *s, const double *v, const double *w,
                             const struct contact *c, struct effect *e) {
    double gv[3];
    if (m->gravity) {
        gv[0] = v[0] + m->g[0] * m->dt; gv[1] = v[1] + m->g[1] * m->dt; gv[2] = v[2] + m->g[2] * m->dt;
    } else {
        memcpy(gv, v, sizeof gv);
    }
    const double *n = c->n;
    double rel[3];
    if (m->rot) {
        double a[3] = {n[0] * s->r, n[1] * s->r, n[2] * s->r};
        rel[0] = 0.0 - (gv[0] + (w[1] * a[2] - w[2] * a[1]));
        rel[1] = 0.0 - (gv[1] + (w[2] * a[0] - w[0] * a[2]));
        rel[2] = 0.0 - (gv[2] + (w[0] * a[1] - w[1] * a[0]));
    } else {
        rel[0] = 0.0 - gv[0]; rel[1] = 0.0 - gv[1]; rel[2] = 0.0 - gv[2];
    }
    double j[3], ub = 0.0, arm[3] = {0.0, 0.0, 0.0};
    int has_ub;
    normal_friction(m, rel, n, s->im + 0.0, s->r * s->r * s->ii + 0.0, c->depth, j, &ub, &has_ub);
    if (m->rot) arm_of(n, j, arm);
    side(j, arm, s->im, s->r * s->ii, has_ub, ub, n, m->rot, e);
}

/* rw_response:pair/6: the effects on A and B */
static void pair_response(const struct model *m, const struct sphere *sa, const double *va, const double *wa,
                          const struct sphere *sb, const double *vb, const double *wb, const struct contact *c,
                          struct effect *ea, struct effect *eb) {
    const double *n = c->n;
    double rel[3];
    if (m->rot) {
        double a[3] = {n[0] * sa->r, n[1] * sa->r, n[2] * sa->r};
        double nrb = -sb->r;
        double b[3] = {n[0] * nrb, n[1] * nrb, n[2] * nrb};
        rel[0] = (vb[0] + (wb[1] * b[2] - wb[2] * b[1])) - (va[0] + (wa[1] * a[2] - wa[2] * a[1]));
        rel[1] = (vb[1] + (wb[2] * b[0] - wb[0] * b[2])) - (va[1] + (wa[2] * a[0] - wa[0] * a[2]));
        rel[2] = (vb[2] + (wb[0] * b[1] - wb[1] * b[0])) - (va[2] + (wa[0] * a[1] - wa[1] * a[0]));
    } else {
        rel[0] = vb[0] - va[0]; rel[1] = vb[1] - va[1]; rel[2] = vb[2] - va[2];
    }
    double j[3], ub = 0.0, arm[3] = {0.0, 0.0, 0.0};
    int has_ub;
    normal_friction(m, rel, n, sa->im + sb->im, sa->r * sa->r * sa->ii + sb->r * sb->r * sb->ii, c->depth, j, &ub,
                    &has_ub);
    if (m->rot) arm_of(n, j, arm);
    side(j, arm, sa->im, sa->r * sa->ii, has_ub, ub, n, m->rot, ea);
    side(j, arm, -sb->im, sb->r * sb->ii, has_ub, ub, n, m->rot, eb);
}

/* rw_narrow:sphere_sphere/4 */
static int sphere_sphere(const double *pa, double ra, const double *pb, double rb, struct contact *c) {
    double d[3] = {pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]};
    double sum = ra + rb;
    double l2 = len2_3(d);
    if (!(l2 < sum * sum)) return 0;
    double l = sqrt(l2);
    if (l > 0.0) {
        double s = 1.0 / l;
        c->n[0] = d[0] * s; c->n[1] = d[1] * s; c->n[2] = d[2] * s;
    } else {
        c->n[0] = 0.0; c->n[1] = 1.0; c->n[2] = 0.0;
    }
    c->depth = sum - l;
    return 1;
}

/* Key order of rw_island:merge/2 and lists:sort/1: {Idx, Feature}. */
static inline int key_less(const struct effect *a, const struct effect *b) {
    return a->key < b->key || (a->key == b->key && a->feature < b->feature);
}

/* A member's state. */
struct mstate { double p[3], v[3], q[4], w[3]; };

/* rw_quat:integrate/3 */
static void quat_integrate(const double *q, const double *o, double dt, double *out) {
    if (o[0] == 0.0 && o[1] == 0.0 && o[2] == 0.0) { memcpy(out, q, 4 * sizeof *q); return; }
    double X = q[0], Y = q[1], Z = q[2], W = q[3], ox = o[0], oy = o[1], oz = o[2];
    double dX = (X * 0.0 + ox * W) + (oy * Z - oz * Y);
    double dY = (Y * 0.0 + oy * W) + (oz * X - ox * Z);
    double dZ = (Z * 0.0 + oz * W) + (ox * Y - oy * X);
    double dW = 0.0 * W - (ox * X + oy * Y + oz * Z);
    double h = 0.5 * dt;
    double X1 = X + dX * h, Y1 = Y + dY * h, Z1 = Z + dZ * h, W1 = W + dW * h;
    double l = sqrt(X1 * X1 + Y1 * Y1 + Z1 * Z1 + W1 * W1);
    if (l > 0.0) {
        double s = 1.0 / l;
        out[0] = X1 * s; out[1] = Y1 * s; out[2] = Z1 * s; out[3] = W1 / l;
    } else {
        out[0] = X1; out[1] = Y1; out[2] = Z1; out[3] = W1;
    }
}

/* rw_integrate:advance/5 */
static void advance(const struct model *m, const struct mstate *st, const double *v, const double *w,
                    const double *u, struct mstate *out) {
    int u_zero = u[0] == 0.0 && u[1] == 0.0 && u[2] == 0.0;
    double vu[3];
    for (int i = 0; i < 3; i++) vu[i] = u_zero ? v[i] : v[i] + u[i];
    double dt = m->dt;
    if (!m->gravity) {
        for (int i = 0; i < 3; i++) { out->p[i] = st->p[i] + vu[i] * dt; out->v[i] = v[i]; }
    } else {
        double v1[3];
        for (int i = 0; i < 3; i++) v1[i] = v[i] + m->g[i] * dt;
        if (m->integrator == 0) {
            for (int i = 0; i < 3; i++) out->p[i] = st->p[i] + (u_zero ? v1[i] : v1[i] + u[i]) * dt;
        } else if (m->integrator == 1) {
            for (int i = 0; i < 3; i++) out->p[i] = st->p[i] + vu[i] * dt;
        } else {
            double hh = 0.5 * dt * dt;
            for (int i = 0; i < 3; i++) out->p[i] = (st->p[i] + vu[i] * dt) + m->g[i] * hh;
        }
        memcpy(out->v, v1, sizeof v1);
    }
    if (m->rot) {
        quat_integrate(st->q, w, dt, out->q);
        memcpy(out->w, w, 3 * sizeof *w);
    }
}

/* #st{p, v, q, w} */
static int get_mstate(ErlNifEnv *env, ERL_NIF_TERM term, int rot, struct mstate *s) {
    const ERL_NIF_TERM *r, *q;
    int arity, qa;
    if (!enif_get_tuple(env, term, &arity, &r) || arity != ST_SIZE || !enif_is_identical(r[0], enif_make_atom(env, "st")) ||
        !get_doubles(env, r[ST_P], 3, s->p) || !get_doubles(env, r[ST_V], 3, s->v))
        return 0;
    if (!rot) return enif_is_identical(r[ST_Q], atom_undefined) && enif_is_identical(r[ST_W], atom_undefined);
    return enif_get_tuple(env, r[ST_Q], &qa, &q) && qa == 2 && get_doubles(env, q[0], 3, s->q) &&
           enif_get_double(env, q[1], &s->q[3]) && get_doubles(env, r[ST_W], 3, s->w);
}

static ERL_NIF_TERM make_mstate(ErlNifEnv *env, ERL_NIF_TERM st_atom, const struct mstate *s, int rot) {
    ERL_NIF_TERM q = atom_undefined, w = atom_undefined;
    if (rot) {
        q = enif_make_tuple2(env, make_doubles(env, s->q, 3), enif_make_double(env, s->q[3]));
        w = make_doubles(env, s->w, 3);
    }
    ERL_NIF_TERM r[ST_SIZE];
    r[0] = st_atom;
    r[ST_P] = make_doubles(env, s->p, 3);
    r[ST_V] = make_doubles(env, s->v, 3);
    r[ST_Q] = q;
    r[ST_W] = w;
    return enif_make_tuple_from_array(env, r, ST_SIZE);
}

/* A contact with a body outside at time t: member k's half. */
struct external { ErlNifSInt64 t; int k; struct effect e; };

/* The working memory of one call. */
struct island {
    struct model m;
    int n, nf;
    struct sphere *s;
    struct fixture *f;
    struct mstate *st, *next;
    double *seen;         /* per member: v (3) and w (3) after its fixture contacts */
    size_t *fixed_start;  /* per member: its fixture effects in fixed */
    size_t *fixed_n;
    struct effects fixed, pairs;
    size_t *pair_start, *pair_n; /* per member: its pair effects, sorted, in sorted */
    struct effect *sorted;
    size_t sorted_cap;
    /* the neighbour list: anchors, limit and pairs, and the sweep's items */
    double *anchor;
    struct item *items;
    double limit;
    int listed; /* 0: every pair is tested */
    int *pairs_ab;
    size_t npairs, pairs_cap;
    /* known contacts with bodies outside, by time */
    struct external *ext;
    size_t next_ext, n_ext;
    /* each member's post-response velocities at this substep: v, w, u */
    double *posts;
};

/* A member in the sweep: its anchor's x and its position. */
struct item { double x; int k; };

/* rw_broadphase:sweep/2's order of its items {X, K, ...}: by x (-0.0 and
   0.0 alike), then by position. */
static int item_order(const void *a, const void *b) {
    const struct item *p = a, *q = b;
    if (p->x < q->x) return -1;
    if (p->x > q->x) return 1;
    return (p->k > q->k) - (p->k < q->k);
}

/* Pairs that may touch while every member stays within limit of its
   anchor, relative to the first member's move: rw_island:build/2's list,
   found by its sweep and prune (rw_broadphase:sweep/2 with {skin, Skin}),
   the same float operations, so that it overflows where that raises. */
static int build_list(struct island *is) {
    int n = is->n;
    double rmax = 0.0, scale = 0.0;
    for (int k = 0; k < n; k++) {
        if (k == 0 || is->s[k].r > rmax) rmax = is->s[k].r;
        memcpy(&is->anchor[3 * k], is->st[k].p, 3 * sizeof(double));
        for (int i = 0; i < 3; i++) {
            double a = eabs(is->st[k].p[i]);
            if ((k == 0 && i == 0) || a > scale) scale = a;
        }
    }
    double skin = 0.5 * rmax;
    scale = scale + rmax + skin;
    is->limit = 0.5 * skin - 1.0e-9 * scale;
    is->listed = is->limit > 0.0;
    is->npairs = 0;
    if (!is->listed) return 1;
    for (int k = 0; k < n; k++) {
        is->items[k].x = is->st[k].p[0];
        is->items[k].k = k;
    }
    qsort(is->items, n, sizeof *is->items, item_order);
    for (int i = 0; i < n; i++) {
        int a = is->items[i].k;
        const double *pa = is->st[a].p;
        double ra = is->s[a].r, reach = ra + rmax + skin, xmax = pa[0] + reach;
        for (int j = i + 1; j < n && is->items[j].x < xmax; j++) {
            int b = is->items[j].k;
            const double *pb = is->st[b].p;
            double dy = pb[1] - pa[1], dz = pb[2] - pa[2];
            if (dy >= reach || -dy >= reach || dz >= reach || -dz >= reach) continue;
            double dx = pb[0] - pa[0];
            double d2 = dx * dx + dy * dy + dz * dz, s = ra + is->s[b].r + skin;
            if (!(d2 < s * s)) continue;
            if (is->npairs == is->pairs_cap) {
                size_t cap = is->pairs_cap ? 2 * is->pairs_cap : 256;
                int *p = enif_realloc(is->pairs_ab, 2 * cap * sizeof *p);
                if (!p) return 0;
                is->pairs_ab = p;
                is->pairs_cap = cap;
            }
            is->pairs_ab[2 * is->npairs] = a < b ? a : b;
            is->pairs_ab[2 * is->npairs + 1] = a < b ? b : a;
            is->npairs++;
        }
    }
    return 1;
}

static int list_valid(const struct island *is) {
    if (!is->listed) return 0;
    double drift[3];
    for (int i = 0; i < 3; i++) drift[i] = is->st[0].p[i] - is->anchor[i];
    double l2 = is->limit * is->limit;
    for (int k = 0; k < is->n; k++) {
        double d[3];
        for (int i = 0; i < 3; i++) d[i] = (is->st[k].p[i] - is->anchor[3 * k + i]) - drift[i];
        if (!(len2_3(d) <= l2)) return 0;
    }
    return 1;
}

static int pair_contact(struct island *is, int a, int b) {
    struct contact c;
    if (!sphere_sphere(is->st[a].p, is->s[a].r, is->st[b].p, is->s[b].r, &c)) return 1;
    struct effect *ea = effects_add(&is->pairs);
    if (!ea) return 0;
    struct effect *eb = effects_add(&is->pairs);
    if (!eb) return 0;
    ea = eb - 1;
    pair_response(&is->m, &is->s[a], &is->seen[6 * a], &is->seen[6 * a + 3], &is->s[b], &is->seen[6 * b],
                  &is->seen[6 * b + 3], &c, ea, eb);
    /* (the member each belongs to, in feature until sorted) */
    ea->key = is->s[b].idx; ea->feature = a;
    eb->key = is->s[a].idx; eb->feature = b;
    return 1;
}

/* The substep at t: is->next from is->st. 0: out of memory. */
static int island_substep(struct island *is, ErlNifSInt64 t) {
    const struct model *m = &is->m;
    int n = is->n;
    is->fixed.n = 0;
    is->pairs.n = 0;
    for (int k = 0; k < n; k++) {
        const struct sphere *s = &is->s[k];
        const struct mstate *st = &is->st[k];
        double v[3], w[3] = {0.0, 0.0, 0.0};
        memcpy(v, st->v, sizeof v);
        if (m->rot) memcpy(w, st->w, sizeof w);
        is->fixed_start[k] = is->fixed.n;
        /* every contact first (from the position alone), then their
           effects in turn, each on the velocities the ones before left */
        struct contact cs[6];
        int features[6];
        for (int fi = 0; fi < is->nf; fi++) {
            int nc = fixture_contacts(st->p, s->r, &is->f[fi], cs, features);
            for (int ci = 0; ci < nc; ci++) {
                struct effect *e = effects_add(&is->fixed);
                if (!e) return 0;
                e->key = is->f[fi].idx;
                e->feature = features[ci];
                memcpy(e->du, cs[ci].n, sizeof e->du); /* (the contact, until all are found) */
                e->dv[0] = cs[ci].depth;
            }
        }
        is->fixed_n[k] = is->fixed.n - is->fixed_start[k];
        for (size_t i = 0; i < is->fixed_n[k]; i++) {
            struct effect *e = &is->fixed.e[is->fixed_start[k] + i];
            struct contact c;
            memcpy(c.n, e->du, sizeof c.n);
            c.depth = e->dv[0];
            fixture_response(m, s, v, w, &c, e);
            for (int j = 0; j < 3; j++) v[j] = v[j] + e->dv[j];
            if (m->rot) for (int j = 0; j < 3; j++) w[j] = w[j] + e->dw[j];
        }
        memcpy(&is->seen[6 * k], v, sizeof v);
        memcpy(&is->seen[6 * k + 3], w, sizeof w);
    }
    /* contacts among members */
    if (!is->listed || !list_valid(is)) {
        if (!build_list(is)) return 0;
    }
    if (is->listed) {
        for (size_t i = 0; i < is->npairs; i++)
            if (!pair_contact(is, is->pairs_ab[2 * i], is->pairs_ab[2 * i + 1])) return 0;
    } else {
        for (int a = 0; a < n; a++)
            for (int b = a + 1; b < n; b++)
                if (!pair_contact(is, a, b)) return 0;
    }
    /* and those with bodies outside, as pair effects */
    while (is->next_ext < is->n_ext && is->ext[is->next_ext].t < t) is->next_ext++;
    for (size_t i = is->next_ext; i < is->n_ext && is->ext[i].t == t; i++) {
        struct effect *e = effects_add(&is->pairs);
        if (!e) return 0;
        *e = is->ext[i].e;
        e->feature = is->ext[i].k;
    }
    /* each member's pair effects, sorted by key */
    if (is->pairs.n > is->sorted_cap) {
        struct effect *e = enif_realloc(is->sorted, is->pairs.n * sizeof *e);
        if (!e) return 0;
        is->sorted = e;
        is->sorted_cap = is->pairs.n;
    }
    for (int k = 0; k < n; k++) is->pair_n[k] = 0;
    for (size_t i = 0; i < is->pairs.n; i++) is->pair_n[is->pairs.e[i].feature]++;
    size_t at = 0;
    for (int k = 0; k < n; k++) { is->pair_start[k] = at; at += is->pair_n[k]; is->pair_n[k] = 0; }
    for (size_t i = 0; i < is->pairs.n; i++) {
        struct effect e = is->pairs.e[i];
        long k = e.feature;
        e.feature = 0;
        /* insertion into the member's sorted run */
        struct effect *run = &is->sorted[is->pair_start[k]];
        size_t j = is->pair_n[k]++;
        while (j > 0 && key_less(&e, &run[j - 1])) { run[j] = run[j - 1]; j--; }
        run[j] = e;
    }
    /* the sum in key order, and the next state */
    for (int k = 0; k < n; k++) {
        const struct mstate *st = &is->st[k];
        double v[3], w[3] = {0.0, 0.0, 0.0}, u[3] = {0.0, 0.0, 0.0};
        memcpy(v, st->v, sizeof v);
        if (m->rot) memcpy(w, st->w, sizeof w);
        const struct effect *fa = &is->fixed.e[is->fixed_start[k]], *pa = &is->sorted[is->pair_start[k]];
        size_t nfa = is->fixed_n[k], npa = is->pair_n[k], i = 0, j = 0;
        while (i < nfa || j < npa) {
            const struct effect *e;
            if (i < nfa && j < npa) e = key_less(&fa[i], &pa[j]) ? &fa[i++] : &pa[j++];
            else if (i < nfa) e = &fa[i++];
            else e = &pa[j++];
            for (int c = 0; c < 3; c++) v[c] = v[c] + e->dv[c];
            if (m->rot) for (int c = 0; c < 3; c++) w[c] = w[c] + e->dw[c];
            for (int c = 0; c < 3; c++) u[c] = u[c] + e->du[c];
        }
        double *post = &is->posts[9 * k];
        memcpy(post, v, sizeof v);
        memcpy(post + 3, w, sizeof w);
        memcpy(post + 6, u, sizeof u);
        advance(m, st, v, w, u, &is->next[k]);
    }
    return 1;
}

static void island_free(struct island *is) {
    enif_free(is->s); enif_free(is->f); enif_free(is->st); enif_free(is->next); enif_free(is->seen);
    enif_free(is->fixed_start); enif_free(is->fixed_n); enif_free(is->pair_start); enif_free(is->pair_n);
    enif_free(is->fixed.e); enif_free(is->pairs.e); enif_free(is->sorted); enif_free(is->anchor);
    enif_free(is->pairs_ab); enif_free(is->ext); enif_free(is->posts); enif_free(is->items);
}

/* The next sync point from a list of them (-1: none). */
static int next_sync(ErlNifEnv *env, ERL_NIF_TERM *list, ErlNifSInt64 *sync) {
    ERL_NIF_TERM head;
    ErlNifSInt64 last = *sync;
    if (enif_is_empty_list(env, *list)) { *sync = -1; return 1; }
    return enif_get_list_cell(env, *list, &head, list) && enif_get_int64(env, head, sync) && *sync > last;
}

/* {Dv, Dw, Du}: Dw undefined without rotation */
static int get_effect(ErlNifEnv *env, ERL_NIF_TERM term, int rot, struct effect *e) {
    const ERL_NIF_TERM *r;
    int arity;
    if (!enif_get_tuple(env, term, &arity, &r) || arity != 3 || !get_doubles(env, r[0], 3, e->dv) ||
        !get_doubles(env, r[2], 3, e->du))
        return 0;
    if (!rot) return enif_is_identical(r[1], atom_undefined);
    return get_doubles(env, r[1], 3, e->dw);
}

/* [{Time, MemberIdx, PartnerIdx, Effect}], ascending by time */
static int get_externals(ErlNifEnv *env, ERL_NIF_TERM list, struct island *is) {
    unsigned len;
    ERL_NIF_TERM head;
    if (!enif_get_list_length(env, list, &len)) return 0;
    is->ext = enif_alloc((len ? len : 1) * sizeof *is->ext);
    if (!is->ext) return 0;
    for (unsigned i = 0; i < len; i++) {
        const ERL_NIF_TERM *r;
        int arity;
        long member;
        struct external *x = &is->ext[i];
        if (!enif_get_list_cell(env, list, &head, &list) || !enif_get_tuple(env, head, &arity, &r) || arity != 4 ||
            !enif_get_int64(env, r[0], &x->t) || !get_long(env, r[1], &member) || !get_long(env, r[2], &x->e.key) ||
            !get_effect(env, r[3], is->m.rot, &x->e) || (i > 0 && x->t < is->ext[i - 1].t))
            return 0;
        x->e.feature = 0;
        x->k = -1;
        for (int k = 0; k < is->n; k++)
            if (is->s[k].idx == member) x->k = k;
        if (x->k < 0) return 0;
    }
    is->n_ext = len;
    return 1;
}

/*
 * island_run(T, Stop, DtT, Model, Spheres, Fixtures, States, Acc, Syncs, Outside)
 *
 * Model a #model{} without CCD, Spheres the members' #sphere{} (a tuple,
 * ascending idx), Fixtures the scene's #fixture{} list, States their #st{}
 * at T (a tuple); Syncs the sync points from T on (ascending), Outside
 * the known contacts with bodies outside from T on, {Time, MemberIdx,
 * PartnerIdx, Effect} ascending by time. Steps every substep from T while
 * T < Stop (not the group's start: the caller's to know), at most
 * MAX_ISLAND_WORK member-substeps and half a time slice (a group of
 * DIRTY_MEMBERS or more: on a dirty CPU scheduler, at most
 * MAX_ISLAND_WORK_DIRTY and a few milliseconds), and returns
 * {T1, States1, Bins, Acc1, Passed}: the time reached, the states there,
 * per member its states after T up to T1 (rw_states' layout), Acc (none,
 * or for a body alone {First, Box, Reach} measured over its states as
 * free_run/13 measures them) and the sync points passed, ascending,
 * {Ts, States, Posts} with the members' post-response velocities {V, W, U};
 * or fallback.
 */
/* (at most Work member-substeps, and none begun Budget us after Start but
   the first) */
static ERL_NIF_TERM island(ErlNifEnv *env, const ERL_NIF_TERM argv[], ErlNifTime start, ErlNifTime budget, long work) {
    ErlNifSInt64 t, stop, dtt;
    const ERL_NIF_TERM *spheres, *states;
    int n, ns;
    unsigned nf;
    struct island is;
    ERL_NIF_TERM result = atom_fallback, list, head;
    memset(&is, 0, sizeof is);
    if (!enif_get_int64(env, argv[0], &t) || !enif_get_int64(env, argv[1], &stop) ||
        !enif_get_int64(env, argv[2], &dtt) || dtt <= 0 || !get_model(env, argv[3], &is.m) ||
        !enif_get_tuple(env, argv[4], &n, &spheres) || n < 1 || !enif_get_list_length(env, argv[5], &nf) ||
        !enif_get_tuple(env, argv[6], &ns, &states) || ns != n)
        return atom_fallback;
    int measured = !enif_is_identical(argv[7], atom_none), first = 0;
    double box[6], reach = 0.0;
    if (measured) {
        const ERL_NIF_TERM *acc;
        int aa;
        if (n != 1 || !enif_get_tuple(env, argv[7], &aa, &acc) || aa != 3 || !get_doubles(env, acc[1], 6, box) ||
            !enif_get_double(env, acc[2], &reach))
            return atom_fallback;
        if (enif_is_identical(acc[0], atom_some)) first = 1;
        else if (!enif_is_identical(acc[0], atom_none)) return atom_fallback;
    }
    is.n = n;
    is.nf = (int)nf;
    is.s = enif_alloc(n * sizeof *is.s);
    is.f = enif_alloc((nf ? nf : 1) * sizeof *is.f);
    is.st = enif_alloc(n * sizeof *is.st);
    is.next = enif_alloc(n * sizeof *is.next);
    is.seen = enif_alloc(6 * n * sizeof *is.seen);
    is.fixed_start = enif_alloc(n * sizeof(size_t));
    is.fixed_n = enif_alloc(n * sizeof(size_t));
    is.pair_start = enif_alloc(n * sizeof(size_t));
    is.pair_n = enif_alloc(n * sizeof(size_t));
    is.anchor = enif_alloc(3 * n * sizeof(double));
    is.items = enif_alloc(n * sizeof *is.items);
    is.posts = enif_alloc(9 * n * sizeof(double));
    ErlNifBinary *bins = enif_alloc(n * sizeof *bins);
    /* the members' terms of a sync point passed, or of the end: states,
       then posts (on the heap: a group may be large) */
    ERL_NIF_TERM *terms = enif_alloc(2 * n * sizeof *terms);
    int nbins = 0;
    if (!is.s || !is.f || !is.st || !is.next || !is.seen || !is.fixed_start || !is.fixed_n || !is.pair_start ||
        !is.pair_n || !is.anchor || !is.items || !is.posts || !bins || !terms)
        goto done;
    for (int k = 0; k < n; k++)
        if (!get_sphere(env, spheres[k], &is.s[k]) || !get_mstate(env, states[k], is.m.rot, &is.st[k])) goto done;
    list = argv[5];
    for (unsigned i = 0; i < nf; i++)
        if (!enif_get_list_cell(env, list, &head, &list) || !get_fixture(env, head, &is.f[i])) goto done;

    if (!get_externals(env, argv[9], &is)) goto done;

    if (t < 0 || stop > INT64_MAX - dtt) goto done;
    ErlNifSInt64 max = substeps(t, stop, dtt, work / n > 0 ? work / n : 1);
    size_t record = is.m.rot ? 13 * 8 : 6 * 8;
    /* the sync points to pass: their states and posts, kept */
    ERL_NIF_TERM syncs = argv[8], passed = enif_make_list(env, 0), st_atom = enif_make_atom(env, "st");
    ErlNifSInt64 sync = -1;
    if (!next_sync(env, &syncs, &sync)) goto done;
    for (; nbins < n; nbins++)
        if (!enif_alloc_binary(max * record, &bins[nbins])) goto done;

    ErlNifSInt64 steps = 0;
    feclearexcept(FE_ALL_EXCEPT);
    while (steps < max) {
        if (steps > 0 && rw_now() - start >= budget) break;
        if (!island_substep(&is, t)) goto done;
        double step = 0.0;
        const double *np = is.next[0].p, *op = is.st[0].p;
        if (measured && first) step = (eabs(np[0] - op[0]) + eabs(np[1] - op[1])) + eabs(np[2] - op[2]);
        if (fetestexcept(BAD_FLAGS)) break;
        if (t == sync) {
            ERL_NIF_TERM *sts = terms, *posts = terms + n;
            for (int k = 0; k < n; k++) {
                const double *post = &is.posts[9 * k];
                sts[k] = make_mstate(env, st_atom, &is.st[k], is.m.rot);
                posts[k] = enif_make_tuple3(env, make_doubles(env, post, 3),
                                            is.m.rot ? make_doubles(env, post + 3, 3) : atom_undefined,
                                            make_doubles(env, post + 6, 3));
            }
            passed = enif_make_list_cell(env, enif_make_tuple3(env, enif_make_int64(env, t),
                                                               enif_make_tuple_from_array(env, sts, n),
                                                               enif_make_tuple_from_array(env, posts, n)),
                                         passed);
            if (!next_sync(env, &syncs, &sync)) goto done;
        }
        if (measured) {
            if (!first) {
                /* the first state: the box is its position, the reach 0 */
                first = 1;
                for (int i = 0; i < 3; i++) { box[i] = np[i]; box[3 + i] = np[i]; }
                reach = 0.0;
            } else {
                grow(box, &reach, np[0], np[1], np[2], step);
            }
        }
        for (int k = 0; k < n; k++) {
            unsigned char *out = bins[k].data + steps * record;
            const struct mstate *s = &is.next[k];
            for (int i = 0; i < 3; i++) put_double(out + 8 * i, s->p[i]);
            for (int i = 0; i < 3; i++) put_double(out + 24 + 8 * i, s->v[i]);
            if (is.m.rot) {
                for (int i = 0; i < 4; i++) put_double(out + 48 + 8 * i, s->q[i]);
                for (int i = 0; i < 3; i++) put_double(out + 80 + 8 * i, s->w[i]);
            }
        }
        struct mstate *swap = is.st;
        is.st = is.next;
        is.next = swap;
        steps++;
        t += dtt;
    }
    feclearexcept(FE_ALL_EXCEPT);
    {
        ERL_NIF_TERM out_bins = enif_make_list(env, 0);
        for (int k = n - 1; k >= 0; k--) {
            if (!enif_realloc_binary(&bins[k], steps * record)) goto done;
            out_bins = enif_make_list_cell(env, enif_make_binary(env, &bins[k]), out_bins);
            nbins--;
        }
        for (int k = 0; k < n; k++) terms[k] = make_mstate(env, st_atom, &is.st[k], is.m.rot);
        ERL_NIF_TERM acc = measured ? enif_make_tuple3(env, first ? atom_some : atom_none, make_doubles(env, box, 6),
                                                       enif_make_double(env, reach))
                                    : atom_none;
        ERL_NIF_TERM ascending;
        enif_make_reverse_list(env, passed, &ascending);
        result = enif_make_tuple5(env, enif_make_int64(env, t), enif_make_tuple_from_array(env, terms, n), out_bins,
                                  acc, ascending);
    }
done:
    for (int k = 0; k < nbins; k++) enif_release_binary(&bins[k]);
    enif_free(bins);
    enif_free(terms);
    island_free(&is);
    return result;
}

static ERL_NIF_TERM island_run_dirty(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    (void)argc;
    return island(env, argv, rw_now(), ISLAND_BUDGET_DIRTY_US, MAX_ISLAND_WORK_DIRTY);
}

static ERL_NIF_TERM island_run(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    int n;
    const ERL_NIF_TERM *spheres;
    if (enif_get_tuple(env, argv[4], &n, &spheres) && n >= DIRTY_MEMBERS)
        return enif_schedule_nif(env, "island_run_dirty", ERL_NIF_DIRTY_JOB_CPU_BOUND, island_run_dirty, argc, argv);
    ErlNifTime start = rw_now();
    ERL_NIF_TERM result = island(env, argv, start, ISLAND_BUDGET_US, MAX_ISLAND_WORK);
    rw_spend(env, start);
    return result;
}

/*
 * measure(Bin, Size): rw_states:seal/3's measurement of the positions of
 * the states in Bin (Size bytes each, at most MAX_SCAN): {Box, Reach},
 * Reach undefined where a step between them overflows; or fallback.
 */
static ERL_NIF_TERM measure(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    ErlNifBinary bin;
    ErlNifSInt64 size;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &bin) || !enif_get_int64(env, argv[1], &size) || size < 24 ||
        bin.size == 0 || bin.size % (size_t)size != 0 || bin.size / (size_t)size > MAX_SCAN)
        return atom_fallback;
    size_t n = bin.size / (size_t)size;
    const unsigned char *p = bin.data;
    double px = get_double(p), py = get_double(p + 8), pz = get_double(p + 16), reach = 0.0;
    double box[6] = {px, py, pz, px, py, pz};
    feclearexcept(FE_ALL_EXCEPT);
    for (size_t i = 0; i < n; i++, p += size) {
        double x = get_double(p), y = get_double(p + 8), z = get_double(p + 16);
        grow(box, &reach, x, y, z, (eabs(x - px) + eabs(y - py)) + eabs(z - pz));
        px = x; py = y; pz = z;
    }
    int overflow = fetestexcept(BAD_FLAGS) != 0;
    feclearexcept(FE_ALL_EXCEPT);
    return enif_make_tuple2(env, make_doubles(env, box, 6), overflow ? atom_undefined : enif_make_double(env, reach));
}

/*
 * madvise(MADV_HUGEPAGE) on every private anonymous read-write mapping of
 * at least 1 GiB in this process: the VM's super carrier (+MMscs), from
 * which all its heaps and tables are carved. Returns the bytes advised
 * ({error, Errno} if a call fails; 0 where there is no such mapping, or
 * off Linux).
 */
#define HUGE_MAPPING (1UL << 30)
static ERL_NIF_TERM huge_pages(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    (void)argc;
    (void)argv;
    unsigned long advised = 0;
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    FILE *maps = fopen("/proc/self/maps", "r");
    if (maps == NULL)
        return enif_make_ulong(env, 0);
    char line[512];
    while (fgets(line, sizeof line, maps) != NULL) {
        unsigned long start, end, offset, inode;
        char perms[8], dev[16], path[256] = "";
        int fields = sscanf(line, "%lx-%lx %7s %lx %15s %lu %255s", &start, &end, perms, &offset, dev, &inode, path);
        if (fields < 6 || inode != 0 || path[0] != '\0' || strcmp(perms, "rw-p") != 0 || end - start < HUGE_MAPPING)
            continue;
        int tries = 0, failed;
        while ((failed = madvise((void *)start, end - start, MADV_HUGEPAGE) != 0) && errno == EAGAIN && ++tries < 5)
            ;
        if (failed) {
            int error = errno;
            fclose(maps);
            return enif_make_tuple2(env, enif_make_atom(env, "error"), enif_make_int(env, error));
        }
        advised += end - start;
    }
    fclose(maps);
#endif
    return enif_make_ulong(env, advised);
}

/* The loops whose calls are short by their bounds (MAX_SUBSTEPS, MAX_SCAN),
   their time told to the scheduler. */
#define TIMED(name)                                                                     \
    static ERL_NIF_TERM timed_##name(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) { \
        ErlNifTime start = rw_now();                                                    \
        ERL_NIF_TERM result = name(env, argc, argv);                                    \
        rw_spend(env, start);                                                           \
        return result;                                                                  \
    }
TIMED(free_run)
TIMED(first_touch)
TIMED(measure)

/* layouts(): where this library reads the Erlang records (rw_records.h). */
static ERL_NIF_TERM layouts(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    (void)argc;
    (void)argv;
    return rw_records_layouts(env);
}

static ErlNifFunc funcs[] = {
    {"nif_layouts", 0, layouts, 0},
    {"nif_free_run", 13, timed_free_run, 0},
    {"nif_first_touch", 10, timed_first_touch, 0},
    {"nif_island_run", 10, island_run, 0},
    {"nif_measure", 2, timed_measure, 0},
    /* (it reads a file: off the normal schedulers) */
    {"nif_huge_pages", 0, huge_pages, ERL_NIF_DIRTY_JOB_IO_BOUND},
    {"nif_cells_new", 0, rw_cells_new, 0},
    {"nif_cells_store", 5, rw_cells_store, 0},
    {"nif_cells_probe", 4, rw_cells_probe, 0},
    {"nif_cells_delete", 4, rw_cells_delete, 0},
    {"nif_cells_gc", 3, rw_cells_gc, 0},
    {"nif_cells_free", 1, rw_cells_free, ERL_NIF_DIRTY_JOB_CPU_BOUND},
    {"nif_cells_dump", 1, rw_cells_dump, 0},
};

ERL_NIF_INIT(rw_native, funcs, load, NULL, upgrade, NULL)
