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

/* A result Erlang would refuse (infinite or not a number): with CHECK,
   one result at a time; with BAD_FLAGS, by the floating-point exception
   flags, since the inputs are finite (Erlang floats) and the first result
   that is not finite raises overflow, division by zero or invalid. */
#define CHECK(v) (bad |= !isfinite(v))
#define BAD_FLAGS (FE_OVERFLOW | FE_DIVBYZERO | FE_INVALID)

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
/* rw_integrate:advance/5 (and rw_quat:integrate/3 with rotation) */
void rw_advance(const struct model *m, const struct mstate *st, const double *v, const double *w, const double *u,
                struct mstate *out);
#endif
