/* hood_set_allocator as an engine uses it: installed before any other call, every allocation of
 * the library goes through it (counted here), and a second installation is refused.
 *
 *   alloc_hooks MODEL.hood
 *
 * Prints "allocations: A frees: F" and exits 0 when A > 0, F > 0 and every free matched a block
 * this allocator gave out with the same size and alignment. */
#define _POSIX_C_SOURCE 200112L
#include "hood.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct counts {
    size_t allocations, frees, mismatched;
} counts;

/* Each block is preceded by a header holding its size and alignment, to check the frees. */
typedef struct block_header {
    size_t size, align;
} block_header;

static void *HOOD_CALL counting_alloc(size_t size, size_t align, void *user) {
    counts *c = (counts *)user;
    size_t pad = align > sizeof(block_header) ? align : sizeof(block_header);
    void *base = NULL;
    unsigned char *p;
    if (posix_memalign(&base, align > sizeof(void *) ? align : sizeof(void *), pad + size) != 0) return NULL;
    p = (unsigned char *)base + pad;
    ((block_header *)p)[-1].size = size;
    ((block_header *)p)[-1].align = align;
    c->allocations++;
    return p;
}

static void HOOD_CALL counting_free(void *ptr, size_t size, size_t align, void *user) {
    counts *c = (counts *)user;
    unsigned char *p = (unsigned char *)ptr;
    size_t pad = align > sizeof(block_header) ? align : sizeof(block_header);
    if (((block_header *)p)[-1].size != size || ((block_header *)p)[-1].align != align) c->mismatched++;
    c->frees++;
    free(p - pad);
}

int main(int argc, char **argv) {
    static counts c;
    hood_allocator a;
    hood_model *model = NULL;
    hood_garment *garment = NULL;
    hood_sim *sim = NULL;
    float rest[9 * 3], out[9 * 3];
    uint32_t faces[8 * 3];
    FILE *f;
    long len;
    void *base;
    uint8_t *bytes;
    int i, j, k = 0, s;
    if (argc < 2) return 2;
    memset(&a, 0, sizeof a);
    a.struct_size = sizeof a;
    a.user = &c;
    a.alloc = counting_alloc;
    a.free = counting_free;
    if (hood_set_allocator(&a) != HOOD_OK) return 3;
    if (hood_set_allocator(&a) != HOOD_ERR_TOO_LATE) return 4;

    f = fopen(argv[1], "rb");
    if (!f || fseek(f, 0, SEEK_END) != 0 || (len = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) return 5;
    if (posix_memalign(&base, HOOD_MODEL_ALIGN, (size_t)len) != 0) return 5;
    bytes = (uint8_t *)base;
    if (fread(bytes, 1, (size_t)len, f) != (size_t)len) return 5;
    fclose(f);
    for (j = 0; j < 3; j++)
        for (i = 0; i < 3; i++) {
            rest[3 * (3 * j + i)] = 0.1f * (float)i;
            rest[3 * (3 * j + i) + 1] = 0.0f;
            rest[3 * (3 * j + i) + 2] = 0.1f * (float)j;
        }
    for (j = 0; j < 2; j++)
        for (i = 0; i < 2; i++) {
            uint32_t v = (uint32_t)(3 * j + i);
            uint32_t quad[6] = {v, v + 3, v + 1, v + 1, v + 3, v + 4};
            memcpy(&faces[k], quad, sizeof quad);
            k += 6;
        }
    s = hood_model_load(bytes, (size_t)len, &model);
    if (s == HOOD_OK) s = hood_garment_new(rest, 9, faces, 8, NULL, 0, NULL, &garment);
    if (s == HOOD_OK) s = hood_sim_new(model, garment, NULL, NULL, &sim);
    for (i = 0; s == HOOD_OK && i < 3; i++) s = hood_sim_step(sim, NULL, 0, out, 9);
    if (s != HOOD_OK) {
        fprintf(stderr, "%s: %s\n", hood_status_string((hood_status)s), hood_last_error());
        return 6;
    }
    hood_sim_free(sim);
    hood_garment_free(garment);
    hood_model_free(model);
    free(base);
    printf("allocations: %zu frees: %zu\n", c.allocations, c.frees);
    return c.allocations > 0 && c.frees > 0 && c.mismatched == 0 ? 0 : 1;
}
