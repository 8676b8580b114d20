/* compare.c - load-time comparison of our mesh reader (common/mesh.c) with
 * Assimp's C API, run by bench/meshload/run.sh.
 *
 *     compare FILE...             best of 3 loads per reader per file
 *     compare --broken FILE...    one load each, reporting what each reader
 *                                 does with a broken file
 *
 * Each (reader, file) pair runs in its own child process so that peak memory
 * (wait4's ru_maxrss) belongs to that load alone and a crash in one reader
 * is reported instead of ending the benchmark. Assimp gets only
 * aiProcess_Triangulate: no vertex joining, normals or validation, which is
 * the closest to what our reader does.
 */
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include "mesh.h"

typedef struct result {
    int ok;
    double best_s;
    size_t vertices, triangles;
    size_t non_finite;  /* positions that are NaN/Inf */
    size_t bad_indices; /* indices >= vertex count */
    char msg[400];
} result;

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

static void load_ours(const char *path, result *r)
{
    mesh_t *m = NULL;
    if (mesh_load(path, &m, r->msg, sizeof r->msg) != 0) {
        r->ok = 0;
        return;
    }
    r->ok = 1;
    r->vertices = m->vertex_count;
    r->triangles = m->triangle_count;
    for (size_t i = 0; i < 3 * m->vertex_count; i++)
        r->non_finite += !isfinite(m->positions[i]);
    for (size_t i = 0; i < 3 * m->triangle_count; i++)
        r->bad_indices += m->indices[i] >= m->vertex_count;
    mesh_destroy(&m);
}

static void load_assimp(const char *path, result *r)
{
    const struct aiScene *s = aiImportFile(path, aiProcess_Triangulate);
    if (!s) {
        r->ok = 0;
        snprintf(r->msg, sizeof r->msg, "%s", aiGetErrorString());
        return;
    }
    r->ok = 1;
    for (unsigned i = 0; i < s->mNumMeshes; i++) {
        const struct aiMesh *m = s->mMeshes[i];
        r->vertices += m->mNumVertices;
        for (unsigned v = 0; v < m->mNumVertices; v++)
            r->non_finite += !isfinite(m->mVertices[v].x) + !isfinite(m->mVertices[v].y) +
                             !isfinite(m->mVertices[v].z);
        for (unsigned f = 0; f < m->mNumFaces; f++) {
            const struct aiFace *face = &m->mFaces[f];
            r->triangles += face->mNumIndices == 3;
            for (unsigned k = 0; k < face->mNumIndices; k++)
                r->bad_indices += face->mIndices[k] >= m->mNumVertices;
        }
    }
    aiReleaseImport(s);
}

/* Runs `runs` loads in a child; fills *r and the child's peak RSS (KiB).
 * Returns the child's termination signal, 0 if it exited normally. */
static int run_child(int ours, const char *path, int runs, result *r, long *maxrss_kb)
{
    int fd[2];
    memset(r, 0, sizeof *r);
    if (pipe(fd) != 0) {
        perror("pipe");
        exit(1);
    }
    fflush(stdout);
    pid_t pid = fork();
    if (pid < 0) {
        perror("fork");
        exit(1);
    }
    if (pid == 0) {
        close(fd[0]);
        result best;
        memset(&best, 0, sizeof best);
        best.best_s = 1e30;
        for (int i = 0; i < runs; i++) {
            result cur;
            memset(&cur, 0, sizeof cur);
            double t0 = now();
            if (ours)
                load_ours(path, &cur);
            else
                load_assimp(path, &cur);
            cur.best_s = now() - t0;
            if (cur.best_s < best.best_s)
                best = cur;
        }
        ssize_t w = write(fd[1], &best, sizeof best);
        _exit(w == (ssize_t)sizeof best ? 0 : 1);
    }
    close(fd[1]);
    ssize_t got = read(fd[0], r, sizeof *r);
    close(fd[0]);
    int st = 0;
    struct rusage ru;
    memset(&ru, 0, sizeof ru);
    wait4(pid, &st, 0, &ru);
    *maxrss_kb = ru.ru_maxrss;
    if (WIFSIGNALED(st))
        return WTERMSIG(st);
    if (got != (ssize_t)sizeof *r) {
        memset(r, 0, sizeof *r);
        snprintf(r->msg, sizeof r->msg, "child exited with status %d", WEXITSTATUS(st));
    }
    return 0;
}

static const char *base(const char *p)
{
    const char *s = strrchr(p, '/');
    return s ? s + 1 : p;
}

int main(int argc, char **argv)
{
    int broken = argc > 1 && strcmp(argv[1], "--broken") == 0;
    int first = broken ? 2 : 1;
    if (argc <= first) {
        fprintf(stderr, "usage: %s [--broken] FILE...\n", argv[0]);
        return 2;
    }
    aiEnableVerboseLogging(0);
    if (!broken) {
        printf("%-22s %8s  %-7s %9s %9s %9s %10s %10s\n", "file", "size MB", "reader", "best s",
               "Mtri/s", "peak MB", "vertices", "triangles");
    }
    for (int a = first; a < argc; a++) {
        struct stat st;
        double mb = stat(argv[a], &st) == 0 ? (double)st.st_size / 1e6 : 0.0;
        for (int ours = 1; ours >= 0; ours--) {
            result r;
            long rss = 0;
            int sig = run_child(ours, argv[a], broken ? 1 : 3, &r, &rss);
            const char *who = ours ? "ours" : "assimp";
            if (broken) {
                if (sig)
                    printf("%-24s %-7s CRASHED (signal %d: %s)\n", base(argv[a]), who, sig,
                           strsignal(sig));
                else if (r.ok)
                    printf("%-24s %-7s LOADED: %zu vertices, %zu triangles, %zu non-finite "
                           "coordinates, %zu out-of-range indices\n",
                           base(argv[a]), who, r.vertices, r.triangles, r.non_finite,
                           r.bad_indices);
                else
                    printf("%-24s %-7s rejected: %s\n", base(argv[a]), who, r.msg);
                continue;
            }
            if (sig || !r.ok) {
                printf("%-22s %8.1f  %-7s FAILED: %s\n", base(argv[a]), mb, who,
                       sig ? strsignal(sig) : r.msg);
                continue;
            }
            printf("%-22s %8.1f  %-7s %9.3f %9.2f %9.0f %10zu %10zu\n", base(argv[a]), mb, who,
                   r.best_s, (double)r.triangles / r.best_s / 1e6, (double)rss / 1024.0, r.vertices,
                   r.triangles);
        }
    }
    return 0;
}
