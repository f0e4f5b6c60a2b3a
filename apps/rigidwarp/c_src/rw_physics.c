/* The physics' rules in C (rw_physics.h). */
#include <string.h>
#include "rw_physics.h"

/*
 * Does a sphere of radius r at (x, y, z) certainly touch none of the
 * fixtures, by rw_narrow:fixture/3's own operations? 1: none touched; 0:
 * one may be (a contact, or a shape whose test is left to the Erlang
 * code). Sets *bad where an operation gives no finite double.
 */
int rw_touches_none(const struct fixture *fs, int n, double x, double y, double z, double r, int *bad_out) {
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
int rw_fixture_contacts(const double *p, double r, const struct fixture *f, struct contact *c, int *feature) {
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
void rw_fixture_response(const struct model *m, const struct sphere *s, const double *v, const double *w,
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
void rw_pair_response(const struct model *m, const struct sphere *sa, const double *va, const double *wa,
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
int rw_sphere_sphere(const double *pa, double ra, const double *pb, double rb, struct contact *c) {
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
