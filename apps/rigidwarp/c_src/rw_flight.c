/* A body's free flight in C: free_run/13, rw_chain's substeps of a body
   alone while it stays in its free zone, by the island's rules
   (rw_physics.c). */
#include <string.h>
#include "rw_nifs.h"
#include "rw_slice.h"
#include "rw_terms.h"

/* A call takes at most this many substeps (the caller calls again for
   more): some 40-200 us; substeps in a millisecond, about. */
#define MAX_SUBSTEPS 4096
#define SUBSTEPS_PER_MS 25000
/* the fixtures a body alone may have near it */
#define MAX_NEAR 16

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
ERL_NIF_TERM rw_free_run(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
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
    if (!always && !rw_get_doubles(env, argv[6], 4, zone)) {
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
            if (!enif_get_list_cell(env, list, &head, &list) || !rw_get_fixture(env, head, &fixtures[i]))
                return atom_fallback;
        }
        near = 1;
    }
    gravity = !enif_is_identical(argv[7], atom_undefined);
    if (gravity) {
        if (!rw_get_doubles(env, argv[7], 3, g)) return atom_fallback;
        if (enif_is_identical(argv[8], atom_symplectic_euler)) integrator = 0;
        else if (enif_is_identical(argv[8], atom_explicit_euler)) integrator = 1;
        else if (enif_is_identical(argv[8], atom_verlet)) integrator = 2;
        else return atom_fallback;
    }
    if (!rw_get_doubles(env, argv[9], 6, s)) return atom_fallback;
    rotation = !enif_is_identical(argv[10], atom_undefined);
    if (rotation != !enif_is_identical(argv[11], atom_undefined)) return atom_fallback;
    if (rotation) {
        if (!enif_get_tuple(env, argv[10], &arity, &elems) || arity != 2 || !rw_get_doubles(env, elems[0], 3, q) ||
            !enif_get_double(env, elems[1], &q[3]) || !rw_get_doubles(env, argv[11], 3, w))
            return atom_fallback;
        /* rw_quat:integrate/3: no spin (-0.0 too) leaves the orientation */
        spinning = !(w[0] == 0.0 && w[1] == 0.0 && w[2] == 0.0);
    }
    if (!enif_get_tuple(env, argv[12], &arity, &elems) || arity != 3 || !rw_get_doubles(env, elems[1], 6, box) ||
        !enif_get_double(env, elems[2], &reach))
        return atom_fallback;
    if (enif_is_identical(elems[0], atom_some)) first = 1;
    else if (enif_is_identical(elems[0], atom_none)) first = 0;
    else return atom_fallback;

    if (t < 0 || last > INT64_MAX - dtt) return atom_fallback;
    ErlNifSInt64 max = rw_substeps(t, last, dtt, MAX_SUBSTEPS);
    size_t record = rotation ? 13 * 8 : 6 * 8;
    ErlNifBinary states;
    if (!enif_alloc_binary(max * record, &states)) return atom_fallback;
    unsigned char *out = states.data;
    struct model model = {.dt = dt, .gravity = gravity, .rot = rotation, .integrator = integrator};
    memcpy(model.g, g, sizeof model.g);
    double x = s[0], y = s[1], z = s[2], vx = s[3], vy = s[4], vz = s[5];
    flags_clear();

    ErlNifSInt64 n = 0;
    while (n < max && t < last && t != sync && t != busy) {
        if (!always) {
            double dx = x - zone[0], dy = y - zone[1], dz = z - zone[2];
            double d2 = dx * dx + dy * dy + dz * dz;
            CHECK(dx); CHECK(dy); CHECK(dz); CHECK(dx * dx); CHECK(dy * dy); CHECK(dz * dz); CHECK(d2);
            if (bad) break;
            if (!(d2 <= zone[3])) break;
            if (near && !rw_touches_none(fixtures, (int)nfixtures, x, y, z, radius, &bad)) break;
        }
        /* rw_integrate:move/10 with a zero pseudo-velocity and
           rw_quat:integrate/3, the island's rules */
        double nx, ny, nz, nvx, nvy, nvz, nq[4];
        move_coord(&model, 0, x, vx, 0.0, 1, &nx, &nvx);
        move_coord(&model, 1, y, vy, 0.0, 1, &ny, &nvy);
        move_coord(&model, 2, z, vz, 0.0, 1, &nz, &nvz);
        if (spinning) quat_integrate(q, w, dt, nq);
        double step = 0.0;
        if (first) {
            double p1[3] = {nx, ny, nz}, p0[3] = {x, y, z};
            step = step_of(p1, p0);
        }

        put_double(out, nx); put_double(out + 8, ny); put_double(out + 16, nz);
        put_double(out + 24, nvx); put_double(out + 32, nvy); put_double(out + 40, nvz);
        if (rotation) {
            for (int i = 0; i < 4; i++) put_double(out + 48 + 8 * i, spinning ? nq[i] : q[i]);
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
        if (spinning) memcpy(q, nq, sizeof q);
        t += dtt;
    }
    /* (a result that is not finite, where the Erlang code raises, sets the
       flags; read once at the end, as the call is dropped whole for it: a
       read per substep took as long as the substep) */
    if (flags_bad()) bad = 1;
    flags_clear();
    rw_spend_work(env, (long)n, SUBSTEPS_PER_MS);
    if (bad || !enif_realloc_binary(&states, n * record)) {
        enif_release_binary(&states);
        return atom_fallback;
    }
    double pv[6] = {x, y, z, vx, vy, vz};
    /* (no spin leaves the orientation: the term given) */
    ERL_NIF_TERM orientation =
        rotation ? (spinning ? enif_make_tuple2(env, rw_make_doubles(env, q, 3), enif_make_double(env, q[3]))
                             : argv[10])
                 : atom_undefined;
    return enif_make_tuple5(env, enif_make_int64(env, t), rw_make_doubles(env, pv, 6), orientation,
                            enif_make_binary(env, &states),
                            enif_make_tuple3(env, first ? atom_some : atom_none, rw_make_doubles(env, box, 6),
                                             enif_make_double(env, reach)));
}
