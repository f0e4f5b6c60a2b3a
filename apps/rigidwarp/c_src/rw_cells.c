/*
 * The segments of one TVHT bucket outside the Erlang heap: rw_cells' map
 * of cells, writers and segments, kept in C arrays, with each stored write
 * copied once into an environment of its own that lives as long as a
 * segment refers to it. A bucket of tens of thousands of bodies then has
 * no heap of hundreds of thousands of words to collect again and again,
 * and a probe walks arrays instead of maps.
 *
 * Here is rw_cells' bookkeeping, in integers (which segments a write
 * meets by times, boxes and member spans; storing, truncating and sweeping
 * them), and the scan of the member pairs so found for their first touch
 * (rw_scan.c's, the same float operations as rw_states:first_touch/6).
 * A probe hands back only the pairs of the earliest touch, each with the
 * window of its substep and the other member's payload, and any pair it
 * could not scan with its whole window: rw_cells' Erlang code scans those
 * again and makes the contacts. rw_cells_tests compares the two stores,
 * operation by operation.
 */
#include <erl_nif.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "rw_cells.h"
#include "rw_records.h"
#include "rw_slice.h"

/* A member's span in a segment: present from a to b. */
struct mspan { long idx; ErlNifSInt64 a, b; };

/* One member's payload in a stored write: its box, the term, and what the
   scan for a first touch reads of it (scan: all of that was read). */
struct payload {
    long idx;
    ErlNifSInt64 box[6];
    ERL_NIF_TERM term;
    int scan, has_reach;
    ErlNifSInt64 t0, size;
    double radius, scale, reach;
    ErlNifBinary bin;
};

/* A write as stored: its copy, the writer and T0 in it, per member. */
struct write {
    long refs;
    struct write *next_dead;
    ErlNifEnv *env;
    ERL_NIF_TERM owner;
    ErlNifSInt64 t0;
    size_t n;
    struct payload members[];
};

/* (one member's span, a body's, is kept in the segment itself: ms NULL) */
struct seg {
    ErlNifSInt64 ta, tb, box[6], t0;
    struct write *w;
    size_t n;
    struct mspan *ms, one;
};

static inline struct mspan *seg_ms(struct seg *s) { return s->ms ? s->ms : &s->one; }

/* A writer's segments in a cell, oldest first, and what a probe reads of
   every writer in a cell: the writer (its term in the newest segment's
   write, and its hash), the newest segment's times and box and the end of
   the one before (INT64_MIN: none). With tens of thousands of bodies, a
   read of each writer's segments or write missed the cache; these are in
   the cell's one array of writers. */
struct wsegs {
    ERL_NIF_TERM owner;
    ErlNifUInt64 owner_hash;
    ErlNifSInt64 ta, tb, box[6], prev_tb;
    struct seg *segs;
    size_t n, cap;
};

/* A cell: three coordinates that fit 64 bits, else the bytes of the
   term (big != NULL). */
struct cell {
    struct cell *next;
    uint64_t hash;
    ErlNifSInt64 x, y, z;
    unsigned char *big;
    size_t big_len;
    struct wsegs *writers;
    size_t n, cap;
};

/* (dead: the writes of large groups no segment refers to any more, their
   environments not yet freed: freeing one takes up to milliseconds, which
   rw_cells_free/1 takes on a dirty scheduler) */
struct cells {
    ErlNifMutex *lock;
    struct cell **table;
    size_t size, count;
    struct write *dead;
};

static ErlNifResourceType *cells_type;

/* (the VM's allocators: in its super carrier, which is backed by huge
   pages for large scenes, and without the C library's returning memory
   to the kernel and faulting it in again) */
static void *zalloc(size_t size) {
    void *p = enif_alloc(size);
    if (p) memset(p, 0, size);
    return p;
}

/* Room for one more in an array of *items holding n of cap (doubled,
   from 4). */
static int reserve(void **items, size_t *cap, size_t n, size_t size) {
    if (n < *cap) return 1;
    size_t grown = *cap ? *cap * 2 : 4;
    void *p = enif_realloc(*items, grown * size);
    if (!p) return 0;
    *items = p;
    *cap = grown;
    return 1;
}

/* Scratch memory for one call, freed at its end: from a buffer on the
   stack, then from the allocator (a probe or a store parsed and collected
   into a dozen small blocks each). */
#define SCRATCH 8192
struct arena { unsigned char *buf; size_t size, used; void **more; };

static void *arena_alloc(struct arena *a, size_t n) {
    n = (n + 15) & ~(size_t)15;
    if (a->used + n <= a->size) {
        void *p = a->buf + a->used;
        a->used += n;
        return p;
    }
    void **block = enif_alloc(16 + n);
    if (!block) return NULL;
    block[0] = a->more;
    a->more = block;
    return (unsigned char *)block + 16;
}

static void arena_free(struct arena *a) {
    for (void **b = a->more; b;) {
        void **next = b[0];
        enif_free(b);
        b = next;
    }
}
static ERL_NIF_TERM atom_ok;
/* The answer to a call whose arguments failed to parse (0) or that ran
   out of memory (-1). */
static ERL_NIF_TERM failed(ErlNifEnv *env, int why) {
    return why < 0 ? enif_raise_exception(env, enif_make_atom(env, "enomem")) : enif_make_badarg(env);
}

/* A cell's key, as parsed from {X, Y, Z} (big: the term's bytes, in the
   call's arena, for coordinates past 64 bits). */
struct key {
    uint64_t hash;
    ErlNifSInt64 x, y, z;
    const unsigned char *big;
    size_t big_len;
};

static uint64_t mix(uint64_t h) {
    h ^= h >> 33;
    h *= 0xff51afd7ed558ccdULL;
    h ^= h >> 33;
    h *= 0xc4ceb9fe1a85ec53ULL;
    h ^= h >> 33;
    return h;
}

/* 1: parsed; 0: not a cell's key (badarg); -1: out of memory. */
static int get_key(ErlNifEnv *env, struct arena *ar, ERL_NIF_TERM cell, struct key *k) {
    int arity;
    const ERL_NIF_TERM *xyz;
    if (!enif_get_tuple(env, cell, &arity, &xyz) || arity != 3) return 0;
    k->big = NULL;
    k->big_len = 0;
    if (enif_get_int64(env, xyz[0], &k->x) && enif_get_int64(env, xyz[1], &k->y) &&
        enif_get_int64(env, xyz[2], &k->z)) {
        k->hash = mix((uint64_t)k->x * 0x9e3779b97f4a7c15ULL ^ mix((uint64_t)k->y + mix((uint64_t)k->z)));
        return 1;
    }
    /* far out: integers of any size */
    if (!enif_is_number(env, xyz[0]) || !enif_is_number(env, xyz[1]) || !enif_is_number(env, xyz[2])) return 0;
    ErlNifBinary bin;
    if (!enif_term_to_binary(env, cell, &bin)) return -1;
    unsigned char *big = arena_alloc(ar, bin.size);
    if (!big) {
        enif_release_binary(&bin);
        return -1;
    }
    memcpy(big, bin.data, bin.size);
    k->big = big;
    k->big_len = bin.size;
    enif_release_binary(&bin);
    uint64_t h = 1469598103934665603ULL;
    for (size_t i = 0; i < k->big_len; i++) h = (h ^ k->big[i]) * 1099511628211ULL;
    k->hash = mix(h);
    k->x = k->y = k->z = 0;
    return 1;
}

static int same_key(const struct cell *c, const struct key *k) {
    if (c->hash != k->hash) return 0;
    if (k->big) return c->big && c->big_len == k->big_len && memcmp(c->big, k->big, c->big_len) == 0;
    return !c->big && c->x == k->x && c->y == k->y && c->z == k->z;
}

static struct cell *find_cell(struct cells *cs, const struct key *k) {
    for (struct cell *c = cs->table[k->hash & (cs->size - 1)]; c; c = c->next)
        if (same_key(c, k)) return c;
    return NULL;
}

static int grow_table(struct cells *cs) {
    size_t size = cs->size * 2;
    struct cell **table = zalloc(size * sizeof *table);
    if (!table) return 0;
    for (size_t i = 0; i < cs->size; i++) {
        for (struct cell *c = cs->table[i], *next; c; c = next) {
            next = c->next;
            c->next = table[c->hash & (size - 1)];
            table[c->hash & (size - 1)] = c;
        }
    }
    enif_free(cs->table);
    cs->table = table;
    cs->size = size;
    return 1;
}

static struct cell *add_cell(struct cells *cs, const struct key *k) {
    if (cs->count >= cs->size && !grow_table(cs)) return NULL;
    struct cell *c = zalloc(sizeof *c);
    if (!c) return NULL;
    c->hash = k->hash;
    c->x = k->x;
    c->y = k->y;
    c->z = k->z;
    if (k->big) {
        c->big = enif_alloc(k->big_len);
        if (!c->big) {
            enif_free(c);
            return NULL;
        }
        memcpy(c->big, k->big, k->big_len);
        c->big_len = k->big_len;
    }
    c->next = cs->table[k->hash & (cs->size - 1)];
    cs->table[k->hash & (cs->size - 1)] = c;
    cs->count++;
    return c;
}

/* A write of this many members or more is freed on a dirty scheduler (a
   write of 500 took up to 4 ms); a smaller one at once (a switch to a
   dirty scheduler and back costs more than freeing it). */
#define LARGE_WRITE 64

static void release_write(struct cells *cs, struct write *w) {
    if (--w->refs > 0) return;
    if (w->n >= LARGE_WRITE) {
        w->next_dead = cs->dead;
        cs->dead = w;
    } else {
        enif_free_env(w->env);
        enif_free(w);
    }
}

static void free_dead(struct cells *cs) {
    for (struct write *w = cs->dead, *next; w; w = next) {
        next = w->next_dead;
        enif_free_env(w->env);
        enif_free(w);
    }
    cs->dead = NULL;
}

static void free_seg(struct cells *cs, struct seg *s) {
    release_write(cs, s->w);
    if (s->ms) enif_free(s->ms);
}

static void free_cell(struct cells *cs, struct cell *c) {
    for (size_t i = 0; i < c->n; i++) {
        for (size_t j = 0; j < c->writers[i].n; j++) free_seg(cs, &c->writers[i].segs[j]);
        if (c->writers[i].segs) enif_free(c->writers[i].segs);
    }
    if (c->writers) enif_free(c->writers);
    if (c->big) enif_free(c->big);
    enif_free(c);
}

/* Unlink and free one cell. */
static void drop_cell(struct cells *cs, struct cell *c) {
    for (struct cell **p = &cs->table[c->hash & (cs->size - 1)]; *p; p = &(*p)->next) {
        if (*p == c) {
            *p = c->next;
            cs->count--;
            free_cell(cs, c);
            return;
        }
    }
}

/* Unlink and free the cells left without writers. */
static void drop_empty(struct cells *cs) {
    for (size_t i = 0; i < cs->size; i++) {
        for (struct cell **p = &cs->table[i]; *p;) {
            struct cell *c = *p;
            if (c->n == 0) {
                *p = c->next;
                cs->count--;
                free_cell(cs, c);
            } else {
                p = &c->next;
            }
        }
    }
}

static void cells_dtor(ErlNifEnv *env, void *obj) {
    (void)env;
    struct cells *cs = obj;
    for (size_t i = 0; cs->table && i < cs->size; i++) {
        for (struct cell *c = cs->table[i], *next; c; c = next) {
            next = c->next;
            free_cell(cs, c);
        }
    }
    free_dead(cs);
    if (cs->table) enif_free(cs->table);
    if (cs->lock) enif_mutex_destroy(cs->lock);
}

int rw_cells_load(ErlNifEnv *env) {
    cells_type = enif_open_resource_type(env, NULL, "rw_cells", cells_dtor, ERL_NIF_RT_CREATE | ERL_NIF_RT_TAKEOVER,
                                         NULL);
    atom_ok = enif_make_atom(env, "ok");
    return cells_type ? 0 : 1;
}

static int get_cells(ErlNifEnv *env, ERL_NIF_TERM t, struct cells **cs) {
    return enif_get_resource(env, t, cells_type, (void **)cs);
}

ERL_NIF_TERM rw_cells_new(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    (void)argc;
    (void)argv;
    struct cells *cs = enif_alloc_resource(cells_type, sizeof *cs);
    if (!cs) return failed(env, -1);
    memset(cs, 0, sizeof *cs);
    cs->table = zalloc(64 * sizeof *cs->table);
    /* (the size only with the table: the destructor walks size slots) */
    if (cs->table) cs->size = 64;
    cs->lock = enif_mutex_create("rw_cells");
    if (!cs->table || !cs->lock) {
        enif_release_resource(cs);
        return failed(env, -1);
    }
    ERL_NIF_TERM t = enif_make_resource(env, cs);
    enif_release_resource(cs);
    return t;
}

/* A box {X0, Y0, Z0, X1, Y1, Z1}; a corner past 64 bits makes it all of
   space (a box only ever rules pairs out). */
static int get_box(ErlNifEnv *env, ERL_NIF_TERM t, ErlNifSInt64 *box) {
    int arity;
    const ERL_NIF_TERM *e;
    if (!enif_get_tuple(env, t, &arity, &e) || arity != 6) return 0;
    for (int i = 0; i < 6; i++) {
        if (!enif_get_int64(env, e[i], &box[i])) {
            if (!enif_is_number(env, e[i])) return 0;
            for (int j = 0; j < 3; j++) {
                box[j] = INT64_MIN;
                box[j + 3] = INT64_MAX;
            }
            return 1;
        }
    }
    return 1;
}

static inline int disjoint(const ErlNifSInt64 *a, const ErlNifSInt64 *b) {
    return a[3] < b[0] || b[3] < a[0] || a[4] < b[1] || b[4] < a[1] || a[5] < b[2] || b[5] < a[2];
}

/* The scan's view of a payload {Idx, Writer, Sphere, T0, States, Bounds}:
   the sphere's radius, and of the states (rw_states:for_probes/1) the
   record size, the binary, the scale and the reach. */
static void get_scan(ErlNifEnv *env, ERL_NIF_TERM payload, struct payload *p) {
    int arity;
    const ERL_NIF_TERM *e, *sphere, *sts, *scale;
    p->scan = 0;
    if (!enif_get_tuple(env, payload, &arity, &e) || arity != 6 || !enif_get_tuple(env, e[2], &arity, &sphere) ||
        arity != SPHERE_SIZE || !enif_get_double(env, sphere[SPHERE_RADIUS], &p->radius) || !enif_get_int64(env, e[3], &p->t0) ||
        !enif_get_tuple(env, e[4], &arity, &sts) || arity != 6 || !enif_get_int64(env, sts[0], &p->size) ||
        !enif_inspect_binary(env, sts[3], &p->bin) || !enif_get_tuple(env, sts[4], &arity, &scale) || arity != 1 ||
        !enif_get_double(env, scale[0], &p->scale))
        return;
    p->has_reach = enif_get_double(env, sts[5], &p->reach);
    if (!p->has_reach && !enif_is_atom(env, sts[5])) return;
    p->scan = 1;
}

/* A write {Writer, T0, #{Idx => Payload}, Bounds}: its members' idx and
   boxes (payload {Idx, Writer, Sphere, T0, States, Bounds}), ascending by
   idx. 1, 0 for badarg, -1 out of memory. */
static int cmp_payload(const void *a, const void *b) {
    long x = ((const struct payload *)a)->idx, y = ((const struct payload *)b)->idx;
    return (x > y) - (x < y);
}

static int get_write(ErlNifEnv *env, struct arena *ar, ERL_NIF_TERM t, ERL_NIF_TERM *owner, ErlNifSInt64 *t0,
                     ErlNifSInt64 *box, struct payload **members, size_t *n) {
    int arity;
    const ERL_NIF_TERM *e;
    size_t size;
    if (!enif_get_tuple(env, t, &arity, &e) || arity != 4 || !enif_get_int64(env, e[1], t0) ||
        !enif_get_map_size(env, e[2], &size) || !get_box(env, e[3], box))
        return 0;
    *owner = e[0];
    struct payload *ps = arena_alloc(ar, (size ? size : 1) * sizeof *ps);
    if (!ps) return -1;
    ErlNifMapIterator it;
    if (!enif_map_iterator_create(env, e[2], &it, ERL_NIF_MAP_ITERATOR_FIRST)) return 0;
    size_t i = 0;
    ERL_NIF_TERM key, value;
    int ok = 1;
    while (ok && i < size && enif_map_iterator_get_pair(env, &it, &key, &value)) {
        const ERL_NIF_TERM *p;
        int pa;
        ok = enif_get_long(env, key, &ps[i].idx) && enif_get_tuple(env, value, &pa, &p) && pa == 6 &&
             get_box(env, p[5], ps[i].box);
        ps[i].term = value;
        get_scan(env, value, &ps[i]);
        i++;
        enif_map_iterator_next(env, &it);
    }
    enif_map_iterator_destroy(env, &it);
    if (!ok || i != size) return 0;
    qsort(ps, size, sizeof *ps, cmp_payload);
    *members = ps;
    *n = size;
    return 1;
}

static const struct payload *find_payload(const struct payload *ps, size_t n, long idx) {
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (ps[mid].idx < idx) lo = mid + 1;
        else hi = mid;
    }
    return lo < n && ps[lo].idx == idx ? &ps[lo] : NULL;
}

/* A span {Cell, Ta, Tb, [{Idx, A, B}]}, its cell's key parsed. */
struct span { struct key key; ErlNifSInt64 ta, tb; size_t n; struct mspan *ms; };

/* Every span parsed (and its key) before a call changes anything: 1, 0
   for badarg, -1 out of memory. */
static int get_spans(ErlNifEnv *env, struct arena *ar, ERL_NIF_TERM list, struct span **out, size_t *n_out) {
    unsigned len;
    if (!enif_get_list_length(env, list, &len)) return 0;
    struct span *sp = arena_alloc(ar, (len ? len : 1) * sizeof *sp);
    if (!sp) return -1;
    ERL_NIF_TERM head;
    size_t i = 0;
    while (enif_get_list_cell(env, list, &head, &list)) {
        int arity, parsed;
        const ERL_NIF_TERM *e;
        unsigned mlen;
        if (!enif_get_tuple(env, head, &arity, &e) || arity != 4 || !enif_get_int64(env, e[1], &sp[i].ta) ||
            !enif_get_int64(env, e[2], &sp[i].tb) || !enif_get_list_length(env, e[3], &mlen))
            return 0;
        if ((parsed = get_key(env, ar, e[0], &sp[i].key)) <= 0) return parsed;
        sp[i].ms = arena_alloc(ar, (mlen ? mlen : 1) * sizeof *sp[i].ms);
        if (!sp[i].ms) return -1;
        ERL_NIF_TERM ml = e[3], mh;
        size_t j = 0;
        while (enif_get_list_cell(env, ml, &mh, &ml)) {
            const ERL_NIF_TERM *m;
            if (!enif_get_tuple(env, mh, &arity, &m) || arity != 3 || !enif_get_long(env, m[0], &sp[i].ms[j].idx) ||
                !enif_get_int64(env, m[1], &sp[i].ms[j].a) || !enif_get_int64(env, m[2], &sp[i].ms[j].b))
                return 0;
            j++;
        }
        sp[i].n = j;
        i++;
    }
    *out = sp;
    *n_out = i;
    return 1;
}


/* The copies in ws of its newest segments' times, box and writer. */
static void refresh(struct wsegs *ws) {
    const struct seg *s = &ws->segs[ws->n - 1];
    ws->owner = s->w->owner;
    ws->ta = s->ta;
    ws->tb = s->tb;
    memcpy(ws->box, s->box, sizeof ws->box);
    ws->prev_tb = ws->n > 1 ? ws->segs[ws->n - 2].tb : INT64_MIN;
}

static inline int is_writer(const struct wsegs *ws, ERL_NIF_TERM owner, ErlNifUInt64 hash) {
    return ws->owner_hash == hash && (ws->owner == owner || enif_is_identical(ws->owner, owner));
}

static struct wsegs *find_writer(struct cell *c, ERL_NIF_TERM owner, ErlNifUInt64 hash) {
    for (size_t i = 0; i < c->n; i++)
        if (is_writer(&c->writers[i], owner, hash)) return &c->writers[i];
    return NULL;
}

static ErlNifUInt64 owner_hash(ERL_NIF_TERM owner) { return enif_hash(ERL_NIF_INTERNAL_HASH, owner, 0); }

static void remove_writer(struct cell *c, struct wsegs *ws) {
    enif_free(ws->segs);
    *ws = c->writers[--c->n];
}

/* rw_cells:store/7's segments, as Owner's: each span from Ta =< UpTo on,
   cut at UpTo, in front of the owner's segments in its cell. */
static ERL_NIF_TERM cells_store(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    struct cells *cs;
    ErlNifSInt64 upto, t0, box[6];
    ERL_NIF_TERM owner = argv[1], writer;
    struct payload *ps;
    size_t np, nspans;
    struct span *spans;
    unsigned char scratch[SCRATCH];
    struct arena ar = {scratch, sizeof scratch, 0, NULL};
    (void)argc;
    /* the write's terms, copied once for all its segments here, and read
       from the copy (a small binary is copied with its term) */
    if (!get_cells(env, argv[0], &cs) || !enif_get_int64(env, argv[4], &upto)) return enif_make_badarg(env);
    ErlNifEnv *wenv = enif_alloc_env();
    if (!wenv) return failed(env, -1);
    ERL_NIF_TERM copy = enif_make_copy(wenv, argv[2]);
    int parsed = get_write(wenv, &ar, copy, &writer, &t0, box, &ps, &np);
    if (parsed > 0) parsed = get_spans(env, &ar, argv[3], &spans, &nspans);
    if (parsed <= 0) {
        enif_free_env(wenv);
        arena_free(&ar);
        return failed(env, parsed);
    }
    struct write *w = enif_alloc(sizeof *w + np * sizeof *ps);
    if (!w) {
        enif_free_env(wenv);
        arena_free(&ar);
        return enif_raise_exception(env, enif_make_atom(env, "enomem"));
    }
    w->env = wenv;
    w->owner = enif_make_copy(wenv, owner);
    w->t0 = t0;
    w->refs = 1;
    w->n = np;
    memcpy(w->members, ps, np * sizeof *ps);
    ErlNifUInt64 hash = owner_hash(owner);
    enif_mutex_lock(cs->lock);
    int ok = 1;
    for (size_t i = 0; ok && i < nspans; i++) {
        struct span *sp = &spans[i];
        if (sp->ta > upto) continue;
        struct cell *c = find_cell(cs, &sp->key);
        if (!c) c = add_cell(cs, &sp->key);
        if (!c) {
            ok = 0;
            break;
        }
        struct wsegs *ws = find_writer(c, owner, hash);
        if (!ws) {
            void *writers = c->writers;
            if (!reserve(&writers, &c->cap, c->n, sizeof *c->writers)) {
                ok = 0;
                break;
            }
            c->writers = writers;
            ws = &c->writers[c->n++];
            memset(ws, 0, sizeof *ws);
            ws->owner_hash = hash;
        }
        void *segs = ws->segs;
        if (!reserve(&segs, &ws->cap, ws->n, sizeof *ws->segs)) {
            ok = 0;
            break;
        }
        ws->segs = segs;
        struct seg *s = &ws->segs[ws->n];
        s->ms = NULL;
        if (sp->n > 1 && !(s->ms = enif_alloc(sp->n * sizeof *s->ms))) {
            ok = 0;
            break;
        }
        s->ta = sp->ta;
        s->t0 = t0;
        s->tb = sp->tb < upto ? sp->tb : upto;
        memcpy(s->box, box, sizeof s->box);
        s->n = 0;
        struct mspan *ms = seg_ms(s);
        for (size_t j = 0; j < sp->n; j++) {
            if (sp->ms[j].a > upto) continue;
            ms[s->n] = sp->ms[j];
            if (ms[s->n].b > upto) ms[s->n].b = upto;
            s->n++;
        }
        s->w = w;
        w->refs++;
        ws->n++;
        refresh(ws);
    }
    if (!ok) {
        /* out of memory midway: no writer or cell left empty */
        for (size_t i = 0; i < cs->size; i++)
            for (struct cell *c = cs->table[i]; c; c = c->next)
                for (size_t j = 0; j < c->n;)
                    if (c->writers[j].n == 0) remove_writer(c, &c->writers[j]);
                    else j++;
        drop_empty(cs);
    }
    release_write(cs, w);
    enif_mutex_unlock(cs->lock);
    arena_free(&ar);
    return ok ? atom_ok : enif_raise_exception(env, enif_make_atom(env, "enomem"));
}

/* A pair window: member Me of the prober and O of the write at OT0. */
/* (other: O's payload in w, once the windows are gathered; touch: 1
   found at lo, -1 none, -2 boxes apart, 0 for the Erlang scan) */
struct window {
    long me, o;
    ErlNifSInt64 ot0, lo, hi;
    const struct write *w;
    const struct payload *other;
    int touch;
};

struct windows { struct arena *ar; struct window *w; size_t n, cap; size_t *slots; size_t nslots; };

static uint64_t window_hash(long me, long o, ErlNifSInt64 ot0) {
    return mix(((uint64_t)me << 32) ^ (uint64_t)o ^ mix((uint64_t)ot0));
}

static int windows_grow(struct windows *ws) {
    size_t cap = ws->cap ? ws->cap * 2 : 32;
    struct window *nw = arena_alloc(ws->ar, cap * sizeof *nw);
    if (!nw) return 0;
    if (ws->n) memcpy(nw, ws->w, ws->n * sizeof *nw);
    ws->w = nw;
    ws->cap = cap;
    size_t nslots = cap * 2;
    size_t *slots = arena_alloc(ws->ar, nslots * sizeof *slots);
    if (!slots) return 0;
    for (size_t i = 0; i < nslots; i++) slots[i] = SIZE_MAX;
    for (size_t i = 0; i < ws->n; i++) {
        size_t h = window_hash(ws->w[i].me, ws->w[i].o, ws->w[i].ot0) & (nslots - 1);
        while (slots[h] != SIZE_MAX) h = (h + 1) & (nslots - 1);
        slots[h] = i;
    }
    ws->slots = slots;
    ws->nslots = nslots;
    return 1;
}

/* rw_cells:pair_windows/6 and window/5: the window on the pair widened by
   Lo..Hi, for the latest write of the other member at OT0. */
static int add_window(struct windows *ws, long me, long o, const struct seg *sg, ErlNifSInt64 lo, ErlNifSInt64 hi) {
    if (ws->n == ws->cap && !windows_grow(ws)) return 0;
    size_t h = window_hash(me, o, sg->t0) & (ws->nslots - 1);
    while (ws->slots[h] != SIZE_MAX) {
        struct window *x = &ws->w[ws->slots[h]];
        if (x->me == me && x->o == o && x->ot0 == sg->t0) {
            if (lo < x->lo) x->lo = lo;
            if (hi > x->hi) x->hi = hi;
            x->w = sg->w;
            return 1;
        }
        h = (h + 1) & (ws->nslots - 1);
    }
    struct window *x = &ws->w[ws->n];
    x->me = me;
    x->o = o;
    x->ot0 = sg->t0;
    x->lo = lo;
    x->hi = hi;
    x->w = sg->w;
    ws->slots[h] = ws->n++;
    return 1;
}

/* rw_cells:probe/3 but the contacts: the member pairs whose times meet in
   a cell and whose writes' boxes and own boxes overlap, scanned (Dt > 0:
   without CCD), as {MyIdx, OtherIdx, Lo, Hi, OtherPayload} for the Erlang
   scan (rw_native:cells_probe/4). */
ERL_NIF_TERM rw_cells_probe(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    struct cells *cs;
    ErlNifSInt64 t0, box[6];
    ERL_NIF_TERM me;
    struct payload *mine;
    size_t nmine, nspans;
    struct span *spans;
    unsigned char scratch[SCRATCH];
    struct arena ar = {scratch, sizeof scratch, 0, NULL};
    (void)argc;
    ErlNifSInt64 dt;
    ErlNifTime start = rw_now();
    if (!get_cells(env, argv[0], &cs) || !enif_get_int64(env, argv[3], &dt)) return enif_make_badarg(env);
    int parsed = get_write(env, &ar, argv[1], &me, &t0, box, &mine, &nmine);
    if (parsed > 0) parsed = get_spans(env, &ar, argv[2], &spans, &nspans);
    if (parsed <= 0) {
        arena_free(&ar);
        return failed(env, parsed);
    }
    struct windows ws = {&ar, NULL, 0, 0, NULL, 0};
    /* 1, else as failed/2 takes it */
    int ok = 1;
    ErlNifUInt64 my_hash = owner_hash(me);
    enif_mutex_lock(cs->lock);
    for (size_t i = 0; ok > 0 && i < nspans; i++) {
        struct span *sp = &spans[i];
        struct cell *c = find_cell(cs, &sp->key);
        if (!c) continue;
        for (size_t j = 0; ok > 0 && j < c->n; j++) {
            struct wsegs *wr = &c->writers[j];
            /* the newest segment from the copies, the older ones only
               when the one before ends in the window or later */
            if (wr->tb < sp->ta || is_writer(wr, me, my_hash)) continue;
            for (size_t s = wr->n; ok > 0 && s-- > 0;) {
                struct seg *sg = &wr->segs[s];
                if (s == wr->n - 1) {
                    if (wr->ta > sp->tb || disjoint(box, wr->box)) continue;
                } else {
                    if ((s == wr->n - 2 ? wr->prev_tb : sg->tb) < sp->ta) break;
                    if (sg->ta > sp->tb || disjoint(box, sg->box)) continue;
                }
                for (size_t a = 0; ok > 0 && a < sp->n; a++) {
                    const struct mspan *m = &sp->ms[a];
                    const struct mspan *oms = seg_ms(sg);
                    for (size_t b = 0; ok > 0 && b < sg->n; b++) {
                        const struct mspan *om = &oms[b];
                        ErlNifSInt64 lo = om->a > m->a ? om->a : m->a, hi = om->b < m->b ? om->b : m->b;
                        if (lo <= hi && !add_window(&ws, m->idx, om->idx, sg, lo, hi)) ok = -1;
                    }
                }
            }
        }
    }
    /* Each window scanned here where it can be (Dt > 0: without CCD):
       those with no touch are dropped, and of those with one only the
       earliest go back, each as the window of its substep (the Erlang
       scan confirms it and makes the contact); the others go back whole. */
    ErlNifSInt64 first = INT64_MAX;
    for (size_t i = 0; ok > 0 && i < ws.n; i++) {
        struct window *x = &ws.w[i];
        const struct payload *p = find_payload(mine, nmine, x->me), *other = find_payload(x->w->members, x->w->n, x->o);
        if (!p || !other) {
            ok = 0;
            break;
        }
        x->other = other;
        x->touch = 0;
        if (disjoint(p->box, other->box)) {
            x->touch = -2;
            continue;
        }
        /* (times from 0: no difference of them overflows) */
        if (dt <= 0 || !p->scan || !other->scan || p->t0 < 0 || other->t0 < 0 || x->lo < p->t0 ||
            x->lo < other->t0)
            continue;
        double sum = p->radius + other->radius, margin = 0.0, reach = 0.0;
        int has_reach = p->has_reach && other->has_reach;
        if (has_reach) {
            margin = 1.0e-9 * (sum + (other->scale > p->scale ? other->scale : p->scale));
            reach = (p->reach + other->reach) * (1.0 + 1.0e-9);
            if (!isfinite(margin) || !isfinite(reach)) continue;
        }
        ErlNifSInt64 k;
        switch (rw_first_touch(&p->bin, p->size, (x->lo - p->t0) / dt + 1, &other->bin, other->size,
                               (x->lo - other->t0) / dt + 1, (x->hi - x->lo) / dt, sum, margin, has_reach, reach,
                               &k)) {
        case 1:
            x->touch = 1;
            x->lo = x->hi = x->lo + k * dt;
            if (x->lo < first) first = x->lo;
            break;
        case 0:
            x->touch = -1;
            break;
        default:
            break;
        }
    }
    ERL_NIF_TERM result = enif_make_list(env, 0);
    for (size_t i = ws.n; ok > 0 && i-- > 0;) {
        struct window *x = &ws.w[i];
        if (x->touch < 0 || x->lo > first) continue;
        ERL_NIF_TERM t = enif_make_tuple5(env, enif_make_long(env, x->me), enif_make_long(env, x->o),
                                          enif_make_int64(env, x->lo), enif_make_int64(env, x->hi),
                                          enif_make_copy(env, x->other->term));
        result = enif_make_list_cell(env, t, result);
    }
    enif_mutex_unlock(cs->lock);
    arena_free(&ar);
    rw_spend(env, start);
    return ok > 0 ? result : failed(env, ok);
}

/* rw_cells:delete/5's truncation: Owner's segments in Cells end at R. */
static ERL_NIF_TERM cells_delete(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    struct cells *cs;
    ErlNifSInt64 r;
    (void)argc;
    if (!get_cells(env, argv[0], &cs) || !enif_get_int64(env, argv[2], &r) || !enif_is_list(env, argv[3]))
        return enif_make_badarg(env);
    ERL_NIF_TERM owner = argv[1], list = argv[3], head;
    ErlNifUInt64 hash = owner_hash(owner);
    unsigned char scratch[SCRATCH];
    struct arena ar = {scratch, sizeof scratch, 0, NULL};
    unsigned len;
    struct key *keys;
    int parsed = 1;
    if (!enif_get_list_length(env, list, &len)) return enif_make_badarg(env);
    /* every key parsed before anything changes */
    if (!(keys = arena_alloc(&ar, (len ? len : 1) * sizeof *keys))) parsed = -1;
    for (unsigned i = 0; parsed > 0 && i < len; i++)
        parsed = enif_get_list_cell(env, list, &head, &list) ? get_key(env, &ar, head, &keys[i]) : 0;
    if (parsed <= 0) {
        arena_free(&ar);
        return failed(env, parsed);
    }
    enif_mutex_lock(cs->lock);
    for (unsigned i = 0; i < len; i++) {
        struct cell *c = find_cell(cs, &keys[i]);
        if (!c) continue;
        struct wsegs *ws = find_writer(c, owner, hash);
        if (!ws) continue;
        while (ws->n > 0 && ws->segs[ws->n - 1].ta > r) free_seg(cs, &ws->segs[--ws->n]);
        if (ws->n > 0 && ws->segs[ws->n - 1].tb > r) {
            struct seg *s = &ws->segs[ws->n - 1];
            s->tb = r;
            struct mspan *ms = seg_ms(s);
            size_t n = 0;
            for (size_t j = 0; j < s->n; j++) {
                if (ms[j].a > r) continue;
                ms[n] = ms[j];
                if (ms[n].b > r) ms[n].b = r;
                n++;
            }
            s->n = n;
        }
        if (ws->n == 0) {
            remove_writer(c, ws);
            if (c->n == 0) drop_cell(cs, c);
        } else {
            refresh(ws);
        }
    }
    enif_mutex_unlock(cs->lock);
    arena_free(&ar);
    return atom_ok;
}

/* A store's and a delete's time, told to the scheduler (a large group's
   write spans many cells). */
ERL_NIF_TERM rw_cells_store(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    ErlNifTime start = rw_now();
    ERL_NIF_TERM result = cells_store(env, argc, argv);
    rw_spend(env, start);
    return result;
}

ERL_NIF_TERM rw_cells_delete(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    ErlNifTime start = rw_now();
    ERL_NIF_TERM result = cells_delete(env, argc, argv);
    rw_spend(env, start);
    return result;
}

/* rw_cells:gc/2's sweep from where the call before stopped (0: from the
   start): each writer keeps its newest segments that end at Gvt or later,
   and a cell left without writers goes. It stops once half a time slice
   is up (a cell of a tall stack holds hundreds of writers and tens of
   thousands of segments): {Slot, Depth, Writer}, the writer to go on from
   (Depth: the cells kept before it in its slot's chain); at the end ok,
   or free where writes wait to be freed (rw_cells_free/1). The caller
   calls again at once, before anything else changes the cells. */
#define GC_BUDGET_US (RW_SLICE_US / 2)
ERL_NIF_TERM rw_cells_gc(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    struct cells *cs;
    ErlNifSInt64 gvt;
    ErlNifUInt64 slot = 0, depth = 0, writer = 0;
    ErlNifTime start = rw_now();
    const ERL_NIF_TERM *from;
    int arity;
    (void)argc;
    if (!get_cells(env, argv[0], &cs) || !enif_get_int64(env, argv[1], &gvt)) return enif_make_badarg(env);
    if (!enif_is_identical(argv[2], enif_make_int(env, 0)) &&
        !(enif_get_tuple(env, argv[2], &arity, &from) && arity == 3 && enif_get_uint64(env, from[0], &slot) &&
          enif_get_uint64(env, from[1], &depth) && enif_get_uint64(env, from[2], &writer)))
        return enif_make_badarg(env);
    enif_mutex_lock(cs->lock);
    ERL_NIF_TERM result = atom_ok;
    size_t swept = 0;
    for (size_t i = slot; i < cs->size; i++, depth = 0, writer = 0) {
        size_t d = 0;
        for (struct cell **p = &cs->table[i]; *p;) {
            struct cell *c = *p;
            if (d < depth) {
                p = &c->next;
                d++;
                continue;
            }
            for (size_t j = d == depth ? writer : 0; j < c->n;) {
                if (swept > 0 && rw_now() - start >= GC_BUDGET_US) {
                    result = enif_make_tuple3(env, enif_make_uint64(env, i), enif_make_uint64(env, d),
                                              enif_make_uint64(env, j));
                    goto out;
                }
                swept++;
                struct wsegs *ws = &c->writers[j];
                size_t keep = ws->n;
                while (keep > 0 && ws->segs[keep - 1].tb >= gvt) keep--;
                /* segments [keep, n) are kept */
                if (keep > 0) {
                    for (size_t s = 0; s < keep; s++) free_seg(cs, &ws->segs[s]);
                    memmove(ws->segs, ws->segs + keep, (ws->n - keep) * sizeof *ws->segs);
                    ws->n -= keep;
                    if (ws->n > 0) refresh(ws);
                }
                if (ws->n == 0) remove_writer(c, ws);
                else j++;
            }
            if (c->n == 0) {
                *p = c->next;
                cs->count--;
                free_cell(cs, c);
            } else {
                p = &c->next;
                d++;
            }
        }
    }
    if (cs->dead) result = enif_make_atom(env, "free");
out:
    enif_mutex_unlock(cs->lock);
    rw_spend(env, start);
    return result;
}

/* The environments of the writes no segment refers to any more, freed (a
   dirty CPU job: a large group's write holds a map of hundreds of
   payloads, some milliseconds to free). */
ERL_NIF_TERM rw_cells_free(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    struct cells *cs;
    (void)argc;
    if (!get_cells(env, argv[0], &cs)) return enif_make_badarg(env);
    enif_mutex_lock(cs->lock);
    free_dead(cs);
    enif_mutex_unlock(cs->lock);
    return atom_ok;
}

/* Everything stored, as rw_cells' Erlang code holds it: [{Cell, Owner,
   [{Ta, Tb, Bounds, T0, [{Idx, A, B}]}]}], each writer's segments newest
   first (for tests). */
static ERL_NIF_TERM make_box(ErlNifEnv *env, const ErlNifSInt64 *b) {
    return enif_make_tuple6(env, enif_make_int64(env, b[0]), enif_make_int64(env, b[1]), enif_make_int64(env, b[2]),
                            enif_make_int64(env, b[3]), enif_make_int64(env, b[4]), enif_make_int64(env, b[5]));
}

ERL_NIF_TERM rw_cells_dump(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    struct cells *cs;
    (void)argc;
    if (!get_cells(env, argv[0], &cs)) return enif_make_badarg(env);
    ERL_NIF_TERM out = enif_make_list(env, 0);
    enif_mutex_lock(cs->lock);
    for (size_t i = 0; i < cs->size; i++) {
        for (struct cell *c = cs->table[i]; c; c = c->next) {
            ERL_NIF_TERM cell;
            if (c->big) {
                if (!enif_binary_to_term(env, c->big, c->big_len, &cell, 0)) cell = enif_make_atom(env, "undefined");
            } else {
                cell = enif_make_tuple3(env, enif_make_int64(env, c->x), enif_make_int64(env, c->y),
                                        enif_make_int64(env, c->z));
            }
            for (size_t j = 0; j < c->n; j++) {
                struct wsegs *ws = &c->writers[j];
                ERL_NIF_TERM segs = enif_make_list(env, 0);
                for (size_t s = 0; s < ws->n; s++) {
                    struct seg *sg = &ws->segs[s];
                    ERL_NIF_TERM ms = enif_make_list(env, 0);
                    const struct mspan *sms = seg_ms(sg);
                    for (size_t m = sg->n; m-- > 0;)
                        ms = enif_make_list_cell(env, enif_make_tuple3(env, enif_make_long(env, sms[m].idx),
                                                                       enif_make_int64(env, sms[m].a),
                                                                       enif_make_int64(env, sms[m].b)),
                                                 ms);
                    segs = enif_make_list_cell(env, enif_make_tuple5(env, enif_make_int64(env, sg->ta),
                                                                     enif_make_int64(env, sg->tb),
                                                                     make_box(env, sg->box),
                                                                     enif_make_int64(env, sg->t0), ms),
                                               segs);
                }
                out = enif_make_list_cell(
                    env, enif_make_tuple3(env, cell, enif_make_copy(env, ws->owner), segs), out);
            }
        }
    }
    enif_mutex_unlock(cs->lock);
    return out;
}
