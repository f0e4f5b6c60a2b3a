/*
 * The island: a contact group's substeps (rw_island:step/3 without CCD),
 * each member's fixture contacts in turn, the contacts among members and
 * with known bodies outside, the effects summed in canonical order and
 * integrated, the rules of rw_physics.c.
 *
 * Where the free flight checks each intermediate result, this reads the
 * floating-point exception flags (flags_bad()): a substep that raises one
 * is dropped, and the Erlang code takes it, which raises badarith there.
 */
#include <stdlib.h>
#include <string.h>
#include "rw_nifs.h"
#include "rw_slice.h"
#include "rw_terms.h"

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

/* A growable array of effects. */
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

/* Key order of rw_island:merge/2 and lists:sort/1: {Idx, Feature}. */
static inline int key_less(const struct effect *a, const struct effect *b) {
    return a->key < b->key || (a->key == b->key && a->feature < b->feature);
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
    if (!rw_sphere_sphere(is->st[a].p, is->s[a].r, is->st[b].p, is->s[b].r, &c)) return 1;
    struct effect *ea = effects_add(&is->pairs);
    if (!ea) return 0;
    struct effect *eb = effects_add(&is->pairs);
    if (!eb) return 0;
    ea = eb - 1;
    rw_pair_response(&is->m, &is->s[a], &is->seen[6 * a], &is->seen[6 * a + 3], &is->s[b], &is->seen[6 * b],
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
            int nc = rw_fixture_contacts(st->p, s->r, &is->f[fi], cs, features);
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
            rw_fixture_response(m, s, v, w, &c, e);
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
        rw_advance(m, st, v, w, u, &is->next[k]);
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
    if (!enif_get_tuple(env, term, &arity, &r) || arity != 3 || !rw_get_doubles(env, r[0], 3, e->dv) ||
        !rw_get_doubles(env, r[2], 3, e->du))
        return 0;
    if (!rot) return enif_is_identical(r[1], atom_undefined);
    return rw_get_doubles(env, r[1], 3, e->dw);
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
            !enif_get_int64(env, r[0], &x->t) || !rw_get_long(env, r[1], &member) || !rw_get_long(env, r[2], &x->e.key) ||
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
        !enif_get_int64(env, argv[2], &dtt) || dtt <= 0 || !rw_get_model(env, argv[3], &is.m) ||
        !enif_get_tuple(env, argv[4], &n, &spheres) || n < 1 || !enif_get_list_length(env, argv[5], &nf) ||
        !enif_get_tuple(env, argv[6], &ns, &states) || ns != n)
        return atom_fallback;
    int measured = !enif_is_identical(argv[7], atom_none), first = 0;
    double box[6], reach = 0.0;
    if (measured) {
        const ERL_NIF_TERM *acc;
        int aa;
        if (n != 1 || !enif_get_tuple(env, argv[7], &aa, &acc) || aa != 3 || !rw_get_doubles(env, acc[1], 6, box) ||
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
        if (!rw_get_sphere(env, spheres[k], &is.s[k]) || !rw_get_mstate(env, states[k], is.m.rot, &is.st[k])) goto done;
    list = argv[5];
    for (unsigned i = 0; i < nf; i++)
        if (!enif_get_list_cell(env, list, &head, &list) || !rw_get_fixture(env, head, &is.f[i])) goto done;

    if (!get_externals(env, argv[9], &is)) goto done;

    if (t < 0 || stop > INT64_MAX - dtt) goto done;
    ErlNifSInt64 max = rw_substeps(t, stop, dtt, work / n > 0 ? work / n : 1);
    size_t record = is.m.rot ? 13 * 8 : 6 * 8;
    /* the sync points to pass: their states and posts, kept */
    ERL_NIF_TERM syncs = argv[8], passed = enif_make_list(env, 0), st_atom = enif_make_atom(env, "st");
    ErlNifSInt64 sync = -1;
    if (!next_sync(env, &syncs, &sync)) goto done;
    for (; nbins < n; nbins++)
        if (!enif_alloc_binary(max * record, &bins[nbins])) goto done;

    ErlNifSInt64 steps = 0;
    flags_clear();
    while (steps < max) {
        if (steps > 0 && rw_now() - start >= budget) break;
        if (!island_substep(&is, t)) goto done;
        double step = 0.0;
        const double *np = is.next[0].p, *op = is.st[0].p;
        if (measured && first) step = step_of(np, op);
        if (flags_bad()) break;
        if (t == sync) {
            ERL_NIF_TERM *sts = terms, *posts = terms + n;
            for (int k = 0; k < n; k++) {
                const double *post = &is.posts[9 * k];
                sts[k] = rw_make_mstate(env, st_atom, &is.st[k], is.m.rot);
                posts[k] = enif_make_tuple3(env, rw_make_doubles(env, post, 3),
                                            is.m.rot ? rw_make_doubles(env, post + 3, 3) : atom_undefined,
                                            rw_make_doubles(env, post + 6, 3));
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
    flags_clear();
    {
        ERL_NIF_TERM out_bins = enif_make_list(env, 0);
        for (int k = n - 1; k >= 0; k--) {
            if (!enif_realloc_binary(&bins[k], steps * record)) goto done;
            out_bins = enif_make_list_cell(env, enif_make_binary(env, &bins[k]), out_bins);
            nbins--;
        }
        for (int k = 0; k < n; k++) terms[k] = rw_make_mstate(env, st_atom, &is.st[k], is.m.rot);
        ERL_NIF_TERM acc = measured ? enif_make_tuple3(env, first ? atom_some : atom_none, rw_make_doubles(env, box, 6),
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

ERL_NIF_TERM rw_island_run(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    int n;
    const ERL_NIF_TERM *spheres;
    if (enif_get_tuple(env, argv[4], &n, &spheres) && n >= DIRTY_MEMBERS)
        return enif_schedule_nif(env, "island_run_dirty", ERL_NIF_DIRTY_JOB_CPU_BOUND, island_run_dirty, argc, argv);
    ErlNifTime start = rw_now();
    ERL_NIF_TERM result = island(env, argv, start, ISLAND_BUDGET_US, MAX_ISLAND_WORK);
    rw_spend(env, start);
    return result;
}
