/* The layouts of rw_records.h as a term, for rw_native's check at load. */
#include "rw_records.h"

struct field { const char *name; int pos; };

#define END {NULL, 0}
static const struct field model[] = {
    {"dt", MODEL_DT}, {"gravity", MODEL_GRAVITY}, {"restitution", MODEL_RESTITUTION}, {"friction", MODEL_FRICTION},
    {"rotation", MODEL_ROTATION}, {"integrator", MODEL_INTEGRATOR}, {"ccd", MODEL_CCD},
    {"rest_speed", MODEL_REST_SPEED}, {"correction", MODEL_CORRECTION}, {"slop", MODEL_SLOP}, END};
static const struct field sphere[] = {
    {"idx", SPHERE_IDX}, {"id", SPHERE_ID}, {"radius", SPHERE_RADIUS}, {"mass", SPHERE_MASS},
    {"inv_mass", SPHERE_INV_MASS}, {"inv_inertia", SPHERE_INV_INERTIA}, END};
static const struct field st[] = {{"p", ST_P}, {"v", ST_V}, {"q", ST_Q}, {"w", ST_W}, END};
static const struct field fixture[] = {
    {"idx", FIXTURE_IDX}, {"id", FIXTURE_ID}, {"shape", FIXTURE_SHAPE}, {"box", FIXTURE_BOX}, END};

static const struct { const char *record; int size; const struct field *fields; } layouts[] = {
    {"model", MODEL_SIZE, model}, {"sphere", SPHERE_SIZE, sphere}, {"st", ST_SIZE, st},
    {"fixture", FIXTURE_SIZE, fixture}};

ERL_NIF_TERM rw_records_layouts(ErlNifEnv *env) {
    ERL_NIF_TERM out = enif_make_list(env, 0);
    for (int i = (int)(sizeof layouts / sizeof layouts[0]) - 1; i >= 0; i--) {
        ERL_NIF_TERM fields = enif_make_list(env, 0);
        int n = 0;
        while (layouts[i].fields[n].name) n++;
        for (int k = n - 1; k >= 0; k--)
            fields = enif_make_list_cell(env, enif_make_tuple2(env, enif_make_atom(env, layouts[i].fields[k].name),
                                                               enif_make_int(env, layouts[i].fields[k].pos)),
                                         fields);
        out = enif_make_list_cell(env, enif_make_tuple3(env, enif_make_atom(env, layouts[i].record),
                                                        enif_make_int(env, layouts[i].size), fields),
                                  out);
    }
    return out;
}
