/*
 * host_test.c - run the reference player on a host and print every level change.
 *
 * Build and run (binary sequence file written by `lishield-guard firmware --format bin`):
 *     cc -std=c99 -Wall -Wextra -Werror -o host_test host_test.c lishield_player.c
 *     ./host_test SEQ.bin N_LOOPS [CHUNK_TICKS]
 * or with a generated C header compiled in (no file reading):
 *     cc -std=c99 ... -DLSP_SEQUENCE_HEADER='"seq.h"' -o host_test host_test.c lishield_player.c
 *     ./host_test N_LOOPS [CHUNK_TICKS]
 *
 * Prints one line "tick channel level" per change, for ticks < N_LOOPS * period, in the order
 * the player reports them. CHUNK_TICKS = 0 (default) drives the player with lsp_step() as a
 * timer interrupt would; CHUNK_TICKS > 0 drives it with lsp_tick_advance(CHUNK_TICKS).
 * Exit status: 0 ok, 1 bad usage, 2 bad file.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lishield_player.h"

#ifdef LSP_SEQUENCE_HEADER
#include LSP_SEQUENCE_HEADER
#endif

typedef struct {
    uint64_t limit_ticks;
} print_ctx;

static void print_level(void *ctx, uint32_t channel, uint16_t level, uint64_t tick)
{
    const print_ctx *pc = (const print_ctx *)ctx;
    if (tick < pc->limit_ticks) {
        printf("%llu %lu %u\n", (unsigned long long)tick, (unsigned long)channel,
               (unsigned)level);
    }
}

#ifndef LSP_SEQUENCE_HEADER
static uint32_t crc32_ieee(const unsigned char *data, size_t n)
{
    uint32_t crc = 0xFFFFFFFFu;
    size_t i;
    int k;
    for (i = 0; i < n; ++i) {
        crc ^= data[i];
        for (k = 0; k < 8; ++k) {
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
    }
    return crc ^ 0xFFFFFFFFu;
}

static uint32_t rd_u32(const unsigned char *b)
{
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) |
           ((uint32_t)b[3] << 24);
}

static uint16_t rd_u16(const unsigned char *b)
{
    return (uint16_t)(b[0] | (b[1] << 8));
}

static int fail(const char *what)
{
    fprintf(stderr, "host_test: %s\n", what);
    return 2;
}

/* Parse an LSHD v1 file into freshly allocated arrays (see firmware/emit.py). */
static int load_lshd(const char *path, uint32_t **dur, uint16_t **lev, uint32_t *n_steps,
                     uint32_t *n_channels)
{
    FILE *f = fopen(path, "rb");
    unsigned char *buf;
    long size;
    size_t pos, need, i, c;
    uint32_t n_ch, n_rec;

    if (f == NULL) return fail("cannot open file");
    if (fseek(f, 0, SEEK_END) != 0 || (size = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return fail("cannot size file");
    }
    buf = (unsigned char *)malloc((size_t)size + 1u);
    if (buf == NULL || fread(buf, 1, (size_t)size, f) != (size_t)size) {
        fclose(f);
        free(buf);
        return fail("cannot read file");
    }
    fclose(f);
    if (size < 13 || memcmp(buf, "LSHD", 4) != 0) { free(buf); return fail("bad magic"); }
    if (rd_u16(buf + 4) != 1u) { free(buf); return fail("unknown version"); }
    n_ch = buf[12];
    pos = 13;
    for (i = 0; i < n_ch; ++i) {
        if (pos >= (size_t)size) { free(buf); return fail("truncated"); }
        pos += 1u + buf[pos];
    }
    if (pos + 4u > (size_t)size) { free(buf); return fail("truncated"); }
    n_rec = rd_u32(buf + pos);
    pos += 4u;
    need = pos + (size_t)n_rec * (4u + 2u * n_ch) + 4u;
    if ((size_t)size != need) { free(buf); return fail("truncated or trailing bytes"); }
    if (rd_u32(buf + need - 4u) != crc32_ieee(buf, need - 4u)) {
        free(buf);
        return fail("CRC mismatch");
    }
    *dur = (uint32_t *)malloc(sizeof(uint32_t) * (n_rec ? n_rec : 1u));
    *lev = (uint16_t *)malloc(sizeof(uint16_t) * (n_rec ? n_rec : 1u) * (n_ch ? n_ch : 1u));
    if (*dur == NULL || *lev == NULL) { free(buf); return fail("out of memory"); }
    for (i = 0; i < n_rec; ++i) {
        (*dur)[i] = rd_u32(buf + pos);
        pos += 4u;
        for (c = 0; c < n_ch; ++c) {
            (*lev)[i * n_ch + c] = rd_u16(buf + pos);
            pos += 2u;
        }
    }
    free(buf);
    *n_steps = n_rec;
    *n_channels = n_ch;
    return 0;
}
#endif

int main(int argc, char **argv)
{
    lsp_player player;
    print_ctx pc;
    const uint32_t *dur = NULL;
    const uint16_t *lev = NULL;
    uint32_t n_steps = 0u, n_channels = 0u, i;
    uint64_t period = 0u;
    unsigned long n_loops, chunk = 0ul;
    int argi = 1;
#ifndef LSP_SEQUENCE_HEADER
    uint32_t *dur_buf = NULL;
    uint16_t *lev_buf = NULL;
    int rc;
    if (argc < 3 || argc > 4) {
        fprintf(stderr, "usage: %s SEQ.bin N_LOOPS [CHUNK_TICKS]\n", argv[0]);
        return 1;
    }
    rc = load_lshd(argv[1], &dur_buf, &lev_buf, &n_steps, &n_channels);
    if (rc != 0) return rc;
    dur = dur_buf;
    lev = lev_buf;
    argi = 2;
#else
    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: %s N_LOOPS [CHUNK_TICKS]\n", argv[0]);
        return 1;
    }
    dur = lsp_seq_durations_ticks;
    lev = lsp_seq_levels;
    n_steps = LSP_SEQ_N_STEPS;
    n_channels = LSP_SEQ_N_CHANNELS;
#endif
    n_loops = strtoul(argv[argi], NULL, 10);
    if (argc > argi + 1) chunk = strtoul(argv[argi + 1], NULL, 10);
    for (i = 0; i < n_steps; ++i) period += dur[i];
    pc.limit_ticks = period * (uint64_t)n_loops;

    if (lsp_init(&player, dur, lev, n_steps, n_channels, print_level, &pc) != LSP_OK) {
        fprintf(stderr, "host_test: lsp_init rejected the sequence\n");
        return 2;
    }
    if (chunk == 0ul) {
        while (lsp_next_boundary(&player) < pc.limit_ticks) (void)lsp_step(&player);
    } else {
        while (player.now_ticks < pc.limit_ticks) lsp_tick_advance(&player, (uint32_t)chunk);
    }
#ifndef LSP_SEQUENCE_HEADER
    free(dur_buf);
    free(lev_buf);
#endif
    return 0;
}
