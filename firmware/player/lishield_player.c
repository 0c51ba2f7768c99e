/*
 * lishield_player.c - portable C99 reference player for LiShield LED sequences.
 * See lishield_player.h for the contract.
 */
#include "lishield_player.h"

#include <stddef.h>

int lsp_init(lsp_player *p, const uint32_t *durations_ticks, const uint16_t *levels,
             uint32_t n_steps, uint32_t n_channels, lsp_level_fn on_level, void *ctx)
{
    uint32_t i;
    if (p == NULL) {
        return LSP_EINVAL;
    }
    p->n_steps = 0u; /* unusable until validated */
    if (durations_ticks == NULL || levels == NULL || n_steps == 0u || n_channels == 0u) {
        return LSP_EINVAL;
    }
    for (i = 0u; i < n_steps; ++i) {
        if (durations_ticks[i] == 0u) {
            return LSP_EINVAL;
        }
    }
    p->durations_ticks = durations_ticks;
    p->levels = levels;
    p->n_steps = n_steps;
    p->n_channels = n_channels;
    p->on_level = on_level;
    p->ctx = ctx;
    p->step = 0u;
    p->step_start_ticks = 0u;
    p->now_ticks = 0u;
    p->loops = 0u;
    if (on_level != NULL) {
        for (i = 0u; i < n_channels; ++i) {
            on_level(ctx, i, levels[i], 0u);
        }
    }
    return LSP_OK;
}

uint32_t lsp_current_duration(const lsp_player *p)
{
    return p->durations_ticks[p->step];
}

uint16_t lsp_current_level(const lsp_player *p, uint32_t channel)
{
    if (channel >= p->n_channels) {
        return 0u;
    }
    return p->levels[(size_t)p->step * p->n_channels + channel];
}

uint64_t lsp_next_boundary(const lsp_player *p)
{
    return p->step_start_ticks + p->durations_ticks[p->step];
}

uint32_t lsp_step(lsp_player *p)
{
    const uint16_t *old_row = p->levels + (size_t)p->step * p->n_channels;
    const uint16_t *new_row;
    uint32_t c;

    p->step_start_ticks += p->durations_ticks[p->step];
    p->step += 1u;
    if (p->step == p->n_steps) {
        p->step = 0u;
        p->loops += 1u;
    }
    new_row = p->levels + (size_t)p->step * p->n_channels;
    if (p->on_level != NULL) {
        for (c = 0u; c < p->n_channels; ++c) {
            if (new_row[c] != old_row[c]) {
                p->on_level(p->ctx, c, new_row[c], p->step_start_ticks);
            }
        }
    }
    if (p->now_ticks < p->step_start_ticks) {
        p->now_ticks = p->step_start_ticks;
    }
    return p->durations_ticks[p->step];
}

void lsp_tick_advance(lsp_player *p, uint32_t ticks)
{
    uint64_t target = p->now_ticks + ticks;
    while (lsp_next_boundary(p) <= target) {
        (void)lsp_step(p);
    }
    p->now_ticks = target;
}
