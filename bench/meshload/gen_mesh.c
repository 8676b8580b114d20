/* gen_mesh.c - writes a ~1M-triangle test mesh for the mesh-reader benchmark
 * (bench/meshload/run.sh) in three encodings: binary little-endian PLY, ascii
 * PLY and OBJ. The surface is a displaced torus (no poles, so every triangle
 * is well shaped), 1000 x 500 vertices -> 500,000 vertices, 1,000,000
 * triangles. Output goes to a scratch folder, never into the repository.
 *
 *     gen_mesh OUT_DIR
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NU 1000
#define NV 500

static void vertex(int i, int j, float p[3])
{
    const double pi = 3.14159265358979323846;
    double u = 2.0 * pi * i / NU, v = 2.0 * pi * j / NV;
    double r = 0.35 + 0.03 * sin(13.0 * u) * cos(7.0 * v);
    double big = 1.0 + r * cos(v);
    p[0] = (float)(big * cos(u));
    p[1] = (float)(r * sin(v));
    p[2] = (float)(big * sin(u));
}

/* The two triangles of grid cell (i, j), wrapping in both directions. */
static void cell(int i, int j, uint32_t t[6])
{
    uint32_t a = (uint32_t)(j * NU + i), b = (uint32_t)(j * NU + (i + 1) % NU);
    uint32_t c = (uint32_t)(((j + 1) % NV) * NU + (i + 1) % NU),
             d = (uint32_t)(((j + 1) % NV) * NU + i);
    uint32_t v[6] = {a, b, c, a, c, d};
    memcpy(t, v, sizeof v);
}

static FILE *open_out(const char *dir, const char *name)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f) {
        perror(path);
        exit(1);
    }
    return f;
}

static void put_u32le(FILE *f, uint32_t v)
{
    unsigned char b[4] = {(unsigned char)v, (unsigned char)(v >> 8), (unsigned char)(v >> 16),
                          (unsigned char)(v >> 24)};
    fwrite(b, 1, 4, f);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s OUT_DIR\n", argv[0]);
        return 2;
    }
    const long nverts = (long)NU * NV, ntris = 2L * NU * NV;
    const char *head = "ply\nformat %s 1.0\ncomment displaced torus, bench/meshload/gen_mesh.c\n"
                       "element vertex %ld\nproperty float x\nproperty float y\nproperty float z\n"
                       "element face %ld\nproperty list uchar int vertex_indices\nend_header\n";
    FILE *bin = open_out(argv[1], "torus_1m_le.ply");
    FILE *asc = open_out(argv[1], "torus_1m_ascii.ply");
    FILE *obj = open_out(argv[1], "torus_1m.obj");
    fprintf(bin, head, "binary_little_endian", nverts, ntris);
    fprintf(asc, head, "ascii", nverts, ntris);
    fprintf(obj, "# displaced torus, bench/meshload/gen_mesh.c\no torus\n");
    for (int j = 0; j < NV; j++)
        for (int i = 0; i < NU; i++) {
            float p[3];
            vertex(i, j, p);
            for (int k = 0; k < 3; k++) {
                uint32_t u;
                memcpy(&u, &p[k], 4);
                put_u32le(bin, u);
            }
            fprintf(asc, "%.7g %.7g %.7g\n", p[0], p[1], p[2]);
            fprintf(obj, "v %.7g %.7g %.7g\n", p[0], p[1], p[2]);
        }
    for (int j = 0; j < NV; j++)
        for (int i = 0; i < NU; i++) {
            uint32_t t[6];
            cell(i, j, t);
            for (int k = 0; k < 6; k += 3) {
                fputc(3, bin);
                for (int m = 0; m < 3; m++)
                    put_u32le(bin, t[k + m]);
                fprintf(asc, "3 %u %u %u\n", t[k], t[k + 1], t[k + 2]);
                fprintf(obj, "f %u %u %u\n", t[k] + 1, t[k + 1] + 1, t[k + 2] + 1);
            }
        }
    int bad = ferror(bin) | ferror(asc) | ferror(obj);
    bad |= fclose(bin) | fclose(asc) | fclose(obj);
    if (bad) {
        fprintf(stderr, "gen_mesh: write error\n");
        return 1;
    }
    printf("gen_mesh: %ld vertices, %ld triangles -> %s/torus_1m_{le.ply,ascii.ply,.obj}\n", nverts,
           ntris, argv[1]);
    return 0;
}
