/* Transparent huge pages for the VM's super carrier (huge_pages/0). */
/* (madvise's MADV_HUGEPAGE beside -std=c99) */
#define _DEFAULT_SOURCE
#include <errno.h>
#include <stdio.h>
#include <string.h>
#ifdef __linux__
#include <sys/mman.h>
#endif
#include "rw_nifs.h"

/*
 * madvise(MADV_HUGEPAGE) on every private anonymous read-write mapping of
 * at least 1 GiB in this process: the VM's super carrier (+MMscs), from
 * which all its heaps and tables are carved. Returns the bytes advised
 * ({error, Errno} if a call fails; 0 where there is no such mapping, or
 * off Linux).
 */
#define HUGE_MAPPING (1UL << 30)
ERL_NIF_TERM rw_huge_pages(ErlNifEnv *env, int argc, const ERL_NIF_TERM argv[]) {
    (void)argc;
    (void)argv;
    unsigned long advised = 0;
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    FILE *maps = fopen("/proc/self/maps", "r");
    if (maps == NULL)
        return enif_make_ulong(env, 0);
    char line[512];
    while (fgets(line, sizeof line, maps) != NULL) {
        unsigned long start, end, offset, inode;
        char perms[8], dev[16], path[256] = "";
        int fields = sscanf(line, "%lx-%lx %7s %lx %15s %lu %255s", &start, &end, perms, &offset, dev, &inode, path);
        if (fields < 6 || inode != 0 || path[0] != '\0' || strcmp(perms, "rw-p") != 0 || end - start < HUGE_MAPPING)
            continue;
        int tries = 0, failed;
        while ((failed = madvise((void *)start, end - start, MADV_HUGEPAGE) != 0) && errno == EAGAIN && ++tries < 5)
            ;
        if (failed) {
            int error = errno;
            fclose(maps);
            return enif_make_tuple2(env, enif_make_atom(env, "error"), enif_make_int(env, error));
        }
        advised += end - start;
    }
    fclose(maps);
#endif
    return enif_make_ulong(env, advised);
}
