/* The physics' rules in C, each the same float operations in the same
   order as its Erlang original (rw_narrow, rw_response, rw_integrate,
   rw_quat), so that the results are bit for bit those of the Erlang code
   (IEEE doubles, no fused multiply-add: the Makefile builds with
   -ffp-contract=off). Each rule is written once here, for the free flight
   (rw_flight.c) and the island (rw_island.c). */
#ifndef RW_PHYSICS_H
#define RW_PHYSICS_H
#include <fenv.h>
#include <math.h>
#include <stddef.h>
#include <string.h>

/* A result Erlang would refuse (infinite or not a number): with CHECK,
   one result at a time; with the floating-point exception flags, since
   the inputs are finite (Erlang floats) and the first result that is not
   finite raises overflow, division by zero or invalid: flags_clear()
   before, flags_bad() after. On x86-64 the doubles' flags are the SSE
   unit's (MXCSR), read and cleared directly: the C library's fenv calls
   save and restore the x87 unit's state as well, a tenth of a microsecond
   each, as long as a few substeps. */
#define CHECK(v) (bad |= !isfinite(v))
#if defined(__x86_64__) && defined(__SSE2__)
#include <xmmintrin.h>
/* MXCSR's invalid (0x01), division by zero (0x04) and overflow (0x08)
   flags; 0x3f all six */
static inline void flags_clear(void) { _mm_setcsr(_mm_getcsr() & ~0x3fu); }
static inline int flags_bad(void) { return (_mm_getcsr() & 0x0du) != 0; }
#else
static inline void flags_clear(void) { feclearexcept(FE_ALL_EXCEPT); }
static inline int flags_bad(void) { return fetestexcept(FE_OVERFLOW | FE_DIVBYZERO | FE_INVALID) != 0; }
#endif

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

/* Erlang's min/2 and max/2 (equal terms: the first), abs/1 (-0.0 stays). */
static inline double emin(double a, double b) { return a <= b ? a : b; }
static inline double emax(double a, double b) { return a >= b ? a : b; }
static inline double eabs(double a) { return a < 0.0 ? -a : a; }
static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static inline double len2_3(const double *a) { return a[0] * a[0] + a[1] * a[1] + a[2] * a[2]; }

/* A member's state. */
struct mstate { double p[3], v[3], q[4], w[3]; };

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

/* A body's step between two positions, as rw_states measures its reach. */
static inline double step_of(const double *p, const double *prev) {
    return (eabs(p[0] - prev[0]) + eabs(p[1] - prev[1])) + eabs(p[2] - prev[2]);
}

/* Does a sphere of radius r at (x, y, z) certainly touch none of the n
   fixtures (rw_island:touches_no_fixture/4)? *bad: an operation gave no
   finite double. */
int rw_touches_none(const struct fixture *fs, int n, double x, double y, double z, double r, int *bad_out);
/* rw_narrow:fixture/3: the contacts with f (up to 6) and their features */
int rw_fixture_contacts(const double *p, double r, const struct fixture *f, struct contact *c, int *feature);
/* rw_response:fixture/4 and pair/6 without a time of impact */
void rw_fixture_response(const struct model *m, const struct sphere *s, const double *v, const double *w,
                         const struct contact *c, struct effect *e);
void rw_pair_response(const struct model *m, const struct sphere *sa, const double *va, const double *wa,
                      const struct sphere *sb, const double *vb, const double *wb, const struct contact *c,
                      struct effect *ea, struct effect *eb);
/* rw_narrow:sphere_sphere/4 */
int rw_sphere_sphere(const double *pa, double ra, const double *pb, double rb, struct contact *c);
/* rw_quat:integrate/3 */
static inline void quat_integrate(const double *q, const double *o, double dt, double *out) {
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

/* rw_integrate:move/10, coordinate i: the position and velocity at the
   next substep from position p, post-response velocity v and
   pseudo-velocity u (u_zero: all of u is zero, -0.0 too). The free flight
   calls it on the coordinates it keeps in registers, rw_advance on a
   member's state. */
static inline void move_coord(const struct model *m, int i, double p, double v, double u, int u_zero, double *p1,
                              double *v1) {
    double dt = m->dt, vu = u_zero ? v : v + u;
    if (!m->gravity) {
        *p1 = p + vu * dt;
        *v1 = v;
        return;
    }
    double vg = v + m->g[i] * dt;
    if (m->integrator == 0) *p1 = p + (u_zero ? vg : vg + u) * dt;
    else if (m->integrator == 1) *p1 = p + vu * dt;
    else *p1 = (p + vu * dt) + m->g[i] * (0.5 * dt * dt);
    *v1 = vg;
}

/* rw_integrate:advance/5: a member's next state */
static inline void rw_advance(const struct model *m, const struct mstate *st, const double *v, const double *w,
                              const double *u, struct mstate *out) {
    int u_zero = u[0] == 0.0 && u[1] == 0.0 && u[2] == 0.0;
    for (int i = 0; i < 3; i++) move_coord(m, i, st->p[i], v[i], u[i], u_zero, &out->p[i], &out->v[i]);
    if (m->rot) {
        quat_integrate(st->q, w, m->dt, out->q);
        memcpy(out->w, w, 3 * sizeof *w);
    }
}
#endif
