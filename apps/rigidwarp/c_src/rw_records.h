/* The Erlang records the C code reads by position (rw_physics.hrl): each
   record's tuple size and the position of each field. Code that reads a
   record names its fields by these constants only. The library hands them
   to rw_native as it loads (layouts/0), which compares them with the
   records the Erlang code was compiled with and leaves the library unused
   where they differ. */
#ifndef RW_RECORDS_H
#define RW_RECORDS_H
#include <erl_nif.h>

/* #model{} */
enum { MODEL_DT = 1, MODEL_GRAVITY, MODEL_RESTITUTION, MODEL_FRICTION, MODEL_ROTATION, MODEL_INTEGRATOR, MODEL_CCD,
       MODEL_REST_SPEED, MODEL_CORRECTION, MODEL_SLOP, MODEL_SIZE };
/* #sphere{} */
enum { SPHERE_IDX = 1, SPHERE_ID, SPHERE_RADIUS, SPHERE_MASS, SPHERE_INV_MASS, SPHERE_INV_INERTIA, SPHERE_SIZE };
/* #st{} */
enum { ST_P = 1, ST_V, ST_Q, ST_W, ST_SIZE };
/* #fixture{} */
enum { FIXTURE_IDX = 1, FIXTURE_ID, FIXTURE_SHAPE, FIXTURE_BOX, FIXTURE_SIZE };

/* [{Record, Size, [{Field, Position}]}] for every record above. */
ERL_NIF_TERM rw_records_layouts(ErlNifEnv *env);
#endif
