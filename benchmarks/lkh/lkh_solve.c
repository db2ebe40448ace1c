/* Runs LKH-3 (as shipped in elkai's source distribution) on a TSPLIB problem with LKH parameters from a file;
   prints the tour, one node number per line (built by build.sh; benchmark only). */
#include <stdio.h>
#include <stdlib.h>
#include "gb_string.h"

void ElkaiSolveProblem(gbString params, gbString problem, int *tourSize, int **tourPtr);

static gbString slurp(const char *path) {
    FILE *f = fopen(path, "rb");
    if (!f) { perror(path); exit(2); }
    fseek(f, 0, SEEK_END); long n = ftell(f); fseek(f, 0, SEEK_SET);
    char *buf = malloc(n + 1);
    if (fread(buf, 1, n, f) != (size_t) n) { perror(path); exit(2); }
    buf[n] = 0; fclose(f);
    gbString s = gb_make_string(buf);
    free(buf);
    return s;
}

int main(int argc, char **argv) {
    if (argc != 3) { fprintf(stderr, "usage: lkh_solve PARAMS PROBLEM > TOUR\n"); return 2; }
    int size = 0, *tour = 0;
    ElkaiSolveProblem(slurp(argv[1]), slurp(argv[2]), &size, &tour);
    for (int i = 0; i < size; i++) printf("%d\n", tour[i]);
    return 0;
}
