/*
 * Two hot loops of the Time Warp engine in C, each the same float
 * operations in the same order as its Erlang original, so that the results
 * are bit for bit those of the Erlang code (IEEE doubles, no fused
 * multiply-add: the Makefile builds with -ffp-contract=off):
 *
 *   free_run/13     rw_chain's free flight of a body alone, while it stays
 *                   in its free zone and meets no sync point, busy substep
 *                   or the step's end;
 *   first_touch/10  rw_states:first_touch/6's scan of two bodies' packed
 *                   positions.
 *
 * Where the Erlang code would raise badarith (a result that is not a
 * finite double) or fail on its arguments these return the atom fallback,
 * and the caller runs the Erlang code from the same point, which does what
 * it does. rw_native.erl loads this library; without it the callers run
 * the Erlang code alone.
 */
#include <erl_nif.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

static ERL_NIF_TERM atom_always, atom_none, atom_some, atom_undefined, atom_fallback, atom_symplectic_euler,
    atom_explicit_euler, atom_verlet, atom_near, atom_fixture, atom_plane, atom_box, atom_hollow, atom_unbounded;

static int load(ErlNifEnv *env, void **priv, ERL_NIF_TERM info) {
    (void)priv;
    (void)info;
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
    return 0;
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

/* A call runs for microseconds, well within a scheduler's time slice:
   free_run/13 takes at most this many substeps (the caller calls again
   for more), first_touch/10 leaves longer scans to the Erlang code. */
#define MAX_SUBSTEPS 4096
#define MAX_SCAN 65536

/* (a result Erlang would refuse: infinite or not a number) */
#define CHECK(v) (bad |= !isfinite(v))

/* A fixture near a body, as rw_narrow:fixture/3 tests it. */
enum shape { PLANE, HOLLOW_BOX, OTHER };
struct fixture {
    int bounded;
    double box[6];     /* its bounding box, when bounded */
    enum shape shape;
    double a[3], b[3]; /* plane: normal and (b[0]) offset; hollow box: centre, half extents */
};
#define MAX_NEAR 16

/* #fixture{shape = Shape, box = Box} */
static int get_fixture(ErlNifEnv *env, ERL_NIF_TERM term, struct fixture *f) {
    const ERL_NIF_TERM *rec, *shape;
    int arity, shape_arity;
    if (!enif_get_tuple(env, term, &arity, &rec) || arity != 5 || !enif_is_identical(rec[0], atom_fixture) ||
        !enif_get_tuple(env, rec[3], &shape_arity, &shape) || shape_arity < 1)
        return 0;
    if (enif_is_identical(rec[4], atom_unbounded)) f->bounded = 0;
    else if (get_doubles(env, rec[4], 6, f->box)) f->bounded = 1;
    else return 0;
    if (enif_is_identical(shape[0], atom_plane) && shape_arity == 3) {
        f->shape = PLANE;
        return get_doubles(env, shape[1], 3, f->a) && enif_get_double(env, shape[2], &f->b[0]);
    }
    if (enif_is_identical(shape[0], atom_box) && shape_arity == 4 && enif_is_identical(shape[3], atom_hollow)) {
        f->shape = HOLLOW_BOX;
        return get_doubles(env, shape[1], 3, f->a) && get_doubles(env, shape[2], 3, f->b);
    }
    f->shape = OTHER;
    return 1;
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
        if (f->shape == PLANE) {
            /* Depth = R - (vdot(N, P) - Off), a contact when above 0.0 */
            double d1 = f->a[0] * x, d2 = f->a[1] * y, d3 = f->a[2] * z;
            double dot = d1 + d2 + d3, rel = dot - f->b[0], depth = r - rel;
            CHECK(d1); CHECK(d2); CHECK(d3); CHECK(d1 + d2); CHECK(dot); CHECK(rel); CHECK(depth);
            if (bad) break;
            if (depth > 0.0) { *bad_out = 0; return 0; }
        } else if (f->shape == HOLLOW_BOX) {
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

    ErlNifSInt64 max = t < last ? (last - t + dtt - 1) / dtt : 0;
    if (max > MAX_SUBSTEPS) max = MAX_SUBSTEPS;
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
            if (nx < box[0]) box[0] = nx;
            if (ny < box[1]) box[1] = ny;
            if (nz < box[2]) box[2] = nz;
            if (nx > box[3]) box[3] = nx;
            if (ny > box[4]) box[4] = ny;
            if (nz > box[5]) box[5] = nz;
            if (step > reach) reach = step;
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
static ERL_NIF_TERM first_touch(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    ErlNifBinary a, b;
    ErlNifSInt64 sa, sb, ia, ib, left, k = 0;
    double sum, margin, reach = 0.0;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &a) || !enif_get_int64(env, argv[1], &sa) ||
        !enif_get_int64(env, argv[2], &ia) || !enif_inspect_binary(env, argv[3], &b) ||
        !enif_get_int64(env, argv[4], &sb) || !enif_get_int64(env, argv[5], &ib) ||
        !enif_get_int64(env, argv[6], &left) || !enif_get_double(env, argv[7], &sum) ||
        !enif_get_double(env, argv[8], &margin) || sa < 24 || sb < 24 || left < 0 || left > MAX_SCAN)
        return atom_fallback;
    int has_reach = enif_get_double(env, argv[9], &reach);
    if (!has_reach && !enif_is_identical(argv[9], atom_undefined)) return atom_fallback;
    int bad = 0;
    double sum2 = sum * sum;
    CHECK(sum2);
    if (bad) return atom_fallback;
    for (;;) {
        if (ia < 1 || ib < 1 || (uint64_t)ia * (uint64_t)sa > a.size || (uint64_t)ib * (uint64_t)sb > b.size)
            return atom_fallback;
        const unsigned char *pa = a.data + (ia - 1) * sa, *pb = b.data + (ib - 1) * sb;
        double dx = get_double(pb) - get_double(pa), dy = get_double(pb + 8) - get_double(pa + 8),
               dz = get_double(pb + 16) - get_double(pa + 16);
        double d2 = dx * dx + dy * dy + dz * dz;
        CHECK(dx); CHECK(dy); CHECK(dz); CHECK(dx * dx); CHECK(dy * dy); CHECK(dz * dz); CHECK(dx * dx + dy * dy);
        CHECK(d2);
        if (bad) return atom_fallback;
        if (d2 < sum2) return enif_make_int64(env, k);
        if (left == 0) return atom_none;
        double gap = sqrt(d2) - sum - margin;
        CHECK(sqrt(d2) - sum); CHECK(gap);
        if (bad) return atom_fallback;
        ErlNifSInt64 skip;
        if (!has_reach || gap <= reach) {
            skip = 0;
        } else {
            double span = (double)left * reach;
            CHECK(span);
            if (bad) return atom_fallback;
            if (gap >= span) {
                skip = left;
            } else {
                double ratio = gap / reach;
                CHECK(ratio);
                if (bad) return atom_fallback;
                skip = (ErlNifSInt64)ratio;
            }
        }
        if (skip >= left) return atom_none;
        ia += skip + 1;
        ib += skip + 1;
        left -= skip + 1;
        k += skip + 1;
    }
}

static ErlNifFunc funcs[] = {
    {"free_run", 13, free_run, 0},
    {"first_touch", 10, first_touch, 0},
};

ERL_NIF_INIT(rw_native, funcs, load, NULL, upgrade, NULL)
