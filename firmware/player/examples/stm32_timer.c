/*
 * stm32_timer.c - example: play a LiShield sequence from an STM32 timer update interrupt.
 *
 * Illustrative only (not built by the tests). Assumes an STM32 with CMSIS device headers,
 * TIM2 (32-bit) as the step timer and TIM3 CH1..CH3 as PWM outputs driving the R, G, B LED
 * drivers. Generate the header with:
 *     lishield-guard firmware table2-rgb --format c -o lishield_seq.h --clock-hz 1000000
 *
 * Timing model
 * ------------
 * TIM2 counts at the sequence clock (LSP_SEQ_CLOCK_HZ, e.g. 1 MHz = 72 MHz / (PSC + 1) with
 * PSC = 71). Each step lasts durations_ticks[i] counts. With ARR preload off (ARPE = 0) the
 * update event fires when a step ends, the counter restarts at 0, and the interrupt writes
 * ARR = next duration - 1, which governs the step that has just begun; the step boundaries
 * therefore stay on exact timer counts (no drift) as long as the interrupt runs before the
 * counter reaches the new ARR. The level writes land a few CPU cycles after the boundary
 * (interrupt latency, constant and far below one tick at 1 MHz on a 72 MHz core). For
 * zero-jitter levels, enable CCR preload (OCxPE = 1) and let TIM2's TRGO fire a TIM3 update
 * (one step of lookahead: call lsp_step one step early and write the *following* levels).
 *
 * The PWM carrier of TIM3 must be much faster than the barcode tones (e.g. 100 kHz or more),
 * or a level can be used as a plain GPIO on/off for on-off keying (max_level == 1).
 *
 * DMA alternative
 * ---------------
 * For zero CPU load, let TIM2's update event trigger DMA: one DMA stream (circular mode) copies
 * the next duration into TIM2->ARR, and a burst transfer via TIM2's DMAR/DCR ("DMA burst")
 * writes the next levels into TIM3->CCR1..CCR3. Lay the data out as interleaved records
 * {ARR, CCR1, CCR2, CCR3} per step (the emitter's arrays can be repacked at build time). The
 * circular DMA then loops the sequence forever with no interrupts at all; lsp_player is still
 * useful on the host to verify the table.
 */
#include <stdint.h>

#include "stm32f4xx.h"     /* CMSIS device header of your part */
#include "lishield_player.h"
#include "lishield_seq.h"  /* generated: lsp_seq_durations_ticks, lsp_seq_levels, LSP_SEQ_* */

static lsp_player g_player;

/* PWM compare value for a level 0..LSP_SEQ_MAX_LEVEL, given TIM3's ARR (PWM resolution). */
static uint32_t level_to_ccr(uint16_t level)
{
    return ((uint32_t)level * (TIM3->ARR + 1u)) / LSP_SEQ_MAX_LEVEL;
}

/* Player callback: write the new level to the channel's compare register (preloaded). */
static void on_level(void *ctx, uint32_t channel, uint16_t level, uint64_t tick)
{
    (void)ctx;
    (void)tick;
    switch (channel) {
    case 0: TIM3->CCR1 = level_to_ccr(level); break;
    case 1: TIM3->CCR2 = level_to_ccr(level); break;
    case 2: TIM3->CCR3 = level_to_ccr(level); break;
    default: break;
    }
    /* GPIO variant for on-off keying: GPIOA->BSRR = level ? (1u << pin) : (1u << (pin + 16)); */
}

void lishield_start(void)
{
    /* Reports step 0's levels (written to the CCRs) and prepares step 0. */
    (void)lsp_init(&g_player, lsp_seq_durations_ticks, lsp_seq_levels, LSP_SEQ_N_STEPS,
                   LSP_SEQ_N_CHANNELS, on_level, 0);
    TIM3->EGR = TIM_EGR_UG;                      /* latch step 0's CCR values now */

    TIM2->PSC = (SystemCoreClock / LSP_SEQ_CLOCK_HZ) - 1u;
    TIM2->ARR = lsp_current_duration(&g_player) - 1u;
    TIM2->CR1 &= ~TIM_CR1_ARPE;                  /* ARR written in the ISR applies at once */
    TIM2->EGR = TIM_EGR_UG;                      /* load PSC and ARR */
    TIM2->SR = 0u;
    TIM2->DIER |= TIM_DIER_UIE;
    NVIC_EnableIRQ(TIM2_IRQn);
    TIM2->CR1 |= TIM_CR1_CEN;
}

/* Fires when the current step's duration has elapsed. */
void TIM2_IRQHandler(void)
{
    if (TIM2->SR & TIM_SR_UIF) {
        TIM2->SR = ~TIM_SR_UIF;
        /* Advance: the callback writes the new levels; the return is the new step's length. */
        TIM2->ARR = lsp_step(&g_player) - 1u;
    }
}
