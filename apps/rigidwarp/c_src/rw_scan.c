/* Two bodies' packed states (rw_states' layout): the scan for their
   first touch, for first_touch/10 and the TVHT's cells (rw_cells.c), and
   the measure of a group's states, measure/2. */
#include <stdint.h>
#include <string.h>
#include "rw_cells.h"
#include "rw_nifs.h"
#include "rw_slice.h"
#include "rw_terms.h"

/* first_touch/10 leaves longer scans to the Erlang code (the reach skips
   most of a long one, and a scan of this many takes well under a
   millisecond). */
#define MAX_SCAN 65536
/* positions measured in a millisecond, about */
#define MEASURED_PER_MS 200000

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

ERL_NIF_TERM rw_first_touch_nif(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
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
 * measure(Bin, Size): rw_states:seal/3's measurement of the positions of
 * the states in Bin (Size bytes each, at most MAX_SCAN): {Box, Reach},
 * Reach undefined where a step between them overflows; or fallback.
 */
ERL_NIF_TERM rw_measure(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    ErlNifBinary bin;
    ErlNifSInt64 size;
    (void)argc;
    if (!enif_inspect_binary(env, argv[0], &bin) || !enif_get_int64(env, argv[1], &size) || size < 24 ||
        bin.size == 0 || bin.size % (size_t)size != 0 || bin.size / (size_t)size > MAX_SCAN)
        return atom_fallback;
    size_t n = bin.size / (size_t)size;
    const unsigned char *p = bin.data;
    double prev[3] = {get_double(p), get_double(p + 8), get_double(p + 16)}, reach = 0.0;
    double box[6] = {prev[0], prev[1], prev[2], prev[0], prev[1], prev[2]};
    flags_clear();
    for (size_t i = 0; i < n; i++, p += size) {
        double pos[3] = {get_double(p), get_double(p + 8), get_double(p + 16)};
        grow(box, &reach, pos[0], pos[1], pos[2], step_of(pos, prev));
        memcpy(prev, pos, sizeof prev);
    }
    int overflow = flags_bad();
    flags_clear();
    rw_spend_work(env, (long)n, MEASURED_PER_MS);
    return enif_make_tuple2(env, rw_make_doubles(env, box, 6), overflow ? atom_undefined : enif_make_double(env, reach));
}
