/*
 * drape.c: a square cloth pinned at two corners over a swaying ellipsoid body, 60 steps.
 *
 *   drape MODEL.hood [GRID]
 *
 * GRID (default 16) is the cloth's vertices per side. Prints timing and the final garment's
 * bounding box. Build (Linux, from the repository root, after `cargo build -p hood-ffi`):
 *
 *   cc -std=c99 -Wall -Wextra -Werror -Iffi/include ffi/examples/drape.c \
 *      target/debug/libhood_ffi.a -lpthread -ldl -lm -o drape
 *
 * Memory check:
 *
 *   valgrind --leak-check=full --error-exitcode=1 ./drape model.hood 8
 */
#include "hood.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define STEPS 60
#define PI_F 3.14159265358979f

static int check(hood_status s, const char *what) {
    if (s != HOOD_OK) {
        fprintf(stderr, "%s failed: %s: %s\n", what, hood_status_string(s), hood_last_error());
        return 0;
    }
    return 1;
}

/* Reads a whole file into a HOOD_MODEL_ALIGN-aligned buffer; *base receives what to free(). */
static uint8_t *read_aligned(const char *path, size_t *len, void **base) {
    FILE *f = fopen(path, "rb");
    long size;
    uint8_t *p;
    if (!f) return NULL;
    if (fseek(f, 0, SEEK_END) != 0 || (size = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return NULL;
    }
    *base = malloc((size_t)size + HOOD_MODEL_ALIGN);
    if (!*base) {
        fclose(f);
        return NULL;
    }
    p = (uint8_t *)*base;
    p += (HOOD_MODEL_ALIGN - (uintptr_t)p % HOOD_MODEL_ALIGN) % HOOD_MODEL_ALIGN;
    if (fread(p, 1, (size_t)size, f) != (size_t)size) {
        fclose(f);
        free(*base);
        return NULL;
    }
    fclose(f);
    *len = (size_t)size;
    return p;
}

/* An ellipsoid with poles on y: 2 + rings * segs vertices, 2 * rings * segs faces (CCW outside). */
static void ellipsoid(int rings, int segs, const float r[3], float *v, uint32_t *f) {
    int i, s, k = 0;
    uint32_t south = (uint32_t)(1 + rings * segs);
    v[0] = 0.0f; v[1] = r[1]; v[2] = 0.0f;
    for (i = 0; i < rings; i++) {
        float th = PI_F * (float)(i + 1) / (float)(rings + 1);
        for (s = 0; s < segs; s++) {
            float ph = 2.0f * PI_F * (float)s / (float)segs;
            float *q = v + 3 * (1 + i * segs + s);
            q[0] = r[0] * sinf(th) * cosf(ph);
            q[1] = r[1] * cosf(th);
            q[2] = r[2] * sinf(th) * sinf(ph);
        }
    }
    v[3 * south] = 0.0f; v[3 * south + 1] = -r[1]; v[3 * south + 2] = 0.0f;
#define ID(ring, seg) ((uint32_t)(1 + (ring) * segs + (seg) % segs))
    for (s = 0; s < segs; s++) {
        f[k++] = 0; f[k++] = ID(0, s + 1); f[k++] = ID(0, s);
    }
    for (i = 0; i + 1 < rings; i++) {
        for (s = 0; s < segs; s++) {
            uint32_t a = ID(i, s), b = ID(i, s + 1), c = ID(i + 1, s + 1), d = ID(i + 1, s);
            f[k++] = a; f[k++] = b; f[k++] = c;
            f[k++] = a; f[k++] = c; f[k++] = d;
        }
    }
    for (s = 0; s < segs; s++) {
        f[k++] = south; f[k++] = ID(rings - 1, s); f[k++] = ID(rings - 1, s + 1);
    }
#undef ID
}

/* An n x n cloth of side `size` at height y, centred on the y axis (CCW seen from +y). */
static void grid(int n, float size, float y, float *v, uint32_t *f) {
    int i, j, k = 0;
    for (j = 0; j < n; j++) {
        for (i = 0; i < n; i++) {
            float *q = v + 3 * (j * n + i);
            q[0] = size * ((float)i / (float)(n - 1) - 0.5f);
            q[1] = y;
            q[2] = size * ((float)j / (float)(n - 1) - 0.5f);
        }
    }
    for (j = 0; j + 1 < n; j++) {
        for (i = 0; i + 1 < n; i++) {
            uint32_t a = (uint32_t)(j * n + i), b = a + 1, c = a + 1 + (uint32_t)n, d = a + (uint32_t)n;
            f[k++] = a; f[k++] = d; f[k++] = c;
            f[k++] = a; f[k++] = c; f[k++] = b;
        }
    }
}

static double now_ms(void) {
    return 1000.0 * (double)clock() / (double)CLOCKS_PER_SEC;
}

int main(int argc, char **argv) {
    const int rings = 16, segs = 24;
    const float radii[3] = {0.25f, 0.3f, 0.25f};
    int n = 16, ok = 0, t;
    size_t i, nv, nf, nb, nbf, moved = 0, model_len = 0;
    void *model_base = NULL;
    uint8_t *model_bytes;
    float *rest = NULL, *body = NULL, *body_rest = NULL, *out = NULL;
    uint32_t *faces = NULL, *body_faces = NULL;
    uint8_t *pinned = NULL;
    hood_model *model = NULL;
    hood_garment *garment = NULL;
    hood_sim *sim = NULL;
    hood_sim_config cfg;
    hood_body_desc bd;
    double t0, elapsed;
    float lo[3], hi[3];

    if (argc < 2) {
        fprintf(stderr, "usage: %s MODEL.hood [GRID]\n", argv[0]);
        return 2;
    }
    if (argc > 2) n = atoi(argv[2]);
    if (n < 2) n = 2;
    if (hood_version() != HOOD_VERSION) {
        fprintf(stderr, "header %d.%d.%d but library %s\n", HOOD_VERSION_MAJOR, HOOD_VERSION_MINOR,
                HOOD_VERSION_PATCH, hood_version_string());
        return 1;
    }
    printf("hood %s\n", hood_version_string());

    model_bytes = read_aligned(argv[1], &model_len, &model_base);
    if (!model_bytes) {
        fprintf(stderr, "cannot read %s\n", argv[1]);
        return 1;
    }

    nv = (size_t)(n * n);
    nf = (size_t)(2 * (n - 1) * (n - 1));
    nb = (size_t)(2 + rings * segs);
    nbf = (size_t)(2 * rings * segs);
    rest = (float *)malloc(3 * nv * sizeof(float));
    out = (float *)malloc(3 * nv * sizeof(float));
    faces = (uint32_t *)malloc(3 * nf * sizeof(uint32_t));
    pinned = (uint8_t *)calloc(nv, 1);
    body_rest = (float *)malloc(3 * nb * sizeof(float));
    body = (float *)malloc(3 * nb * sizeof(float));
    body_faces = (uint32_t *)malloc(3 * nbf * sizeof(uint32_t));
    if (!rest || !out || !faces || !pinned || !body_rest || !body || !body_faces) goto done;

    grid(n, 0.6f, 0.32f, rest, faces);
    pinned[0] = 1;
    pinned[n - 1] = 1;
    ellipsoid(rings, segs, radii, body_rest, body_faces);

    if (!check(hood_model_load(model_bytes, model_len, &model), "hood_model_load")) goto done;
    if (!check(hood_garment_new(rest, nv, faces, nf, NULL, 0, pinned, &garment), "hood_garment_new")) goto done;
    /* Zeroed first (see the header's Conventions on struct_size), then every field set. */
    memset(&bd, 0, sizeof bd);
    bd.struct_size = sizeof(hood_body_desc);
    bd.positions = body_rest;
    bd.n_vertices = nb;
    bd.indices = body_faces;
    bd.n_faces = nbf;
    bd.omitted = NULL;
    hood_sim_config_default(&cfg);
    if (!check(hood_sim_new(model, garment, &bd, &cfg, &sim), "hood_sim_new")) goto done;
    /* The sim keeps its own copy of the garment. */
    if (!check(hood_garment_free(garment), "hood_garment_free")) goto done;
    garment = NULL;
    printf("garment: %zu vertices, body: %zu vertices\n", nv, nb);
    /* A garment authored in the rest pose may start in the body: push it out onto the body's first
     * frame and start the sim from there (this cloth hangs 2 cm above the body: nothing moves). */
    memcpy(out, rest, 3 * nv * sizeof(float));
    if (!check(hood_garment_push_out(&bd, out, nv, pinned, &moved), "hood_garment_push_out")) goto done;
    if (moved > 0 && !check(hood_sim_reset(sim, out, nv, NULL, 0), "hood_sim_reset")) goto done;
    printf("pushed out: %zu vertices\n", moved);

    t0 = now_ms();
    for (t = 1; t <= STEPS; t++) {
        float dx = 0.01f * sinf(0.3f * (float)t);
        for (i = 0; i < nb; i++) {
            body[3 * i] = body_rest[3 * i] + dx;
            body[3 * i + 1] = body_rest[3 * i + 1];
            body[3 * i + 2] = body_rest[3 * i + 2];
        }
        if (!check(hood_sim_step(sim, body, nb, out, nv), "hood_sim_step")) goto done;
    }
    elapsed = now_ms() - t0;

    for (i = 0; i < 3; i++) {
        lo[i] = out[i];
        hi[i] = out[i];
    }
    for (i = 1; i < nv; i++) {
        int k;
        for (k = 0; k < 3; k++) {
            float x = out[3 * i + (size_t)k];
            if (x < lo[k]) lo[k] = x;
            if (x > hi[k]) hi[k] = x;
        }
    }
    printf("steps: %d\n", STEPS);
    printf("time: %.3f ms total, %.3f ms/step (CPU time)\n", elapsed, elapsed / STEPS);
    printf("bbox: min %.6f %.6f %.6f max %.6f %.6f %.6f\n", (double)lo[0], (double)lo[1], (double)lo[2],
           (double)hi[0], (double)hi[1], (double)hi[2]);
    ok = 1;

done:
    /* Sims before their model; every free accepts NULL. */
    if (!check(hood_sim_free(sim), "hood_sim_free")) ok = 0;
    if (!check(hood_garment_free(garment), "hood_garment_free")) ok = 0;
    if (!check(hood_model_free(model), "hood_model_free")) ok = 0;
    free(model_base);
    free(rest);
    free(out);
    free(faces);
    free(pinned);
    free(body_rest);
    free(body);
    free(body_faces);
    return ok ? 0 : 1;
}
