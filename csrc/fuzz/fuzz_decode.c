/* SPDX-License-Identifier: MIT */
/*
 * fuzz_decode.c - libFuzzer target: the block decoders on arbitrary input.
 * The input is the register image (as many registers as it holds, copied
 * into an exactly sized heap buffer so AddressSanitizer sees any overread),
 * the first byte also picks the channel count, the block mask and the
 * humidity units.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../pymb.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t nregs = size / 2, i;
    unsigned channels, mask;
    uint16_t *regs;
    uint8_t *tenths, *wanted, *states;
    double *values;
    pymb_coolpro_telemetry t;
    pymb_coolpro_identity id;
    pymb_hub_request rq;

    if (size < 1) {
        return 0;
    }
    channels = (unsigned)(data[0] % 102); /* 0 and 101 are invalid on purpose */
    mask = (unsigned)(data[size - 1]);
    regs = malloc((nregs ? nregs : 1) * sizeof *regs);
    tenths = malloc(channels ? channels : 1);
    wanted = malloc(PYMB_HUB_BITMAP_BYTES);
    values = malloc((size_t)PYMB_HUB_BLOCKS * (channels ? channels : 1) * sizeof *values);
    states = malloc((size_t)PYMB_HUB_BLOCKS * (channels ? channels : 1));
    if (!regs || !tenths || !wanted || !values || !states) {
        goto out;
    }
    for (i = 0; i < nregs; i++) {
        regs[i] = (uint16_t)(data[2 * i] << 8 | data[2 * i + 1]);
    }
    for (i = 0; i < channels; i++) {
        tenths[i] = (uint8_t)(data[i % size] & 1u);
    }
    for (i = 0; i < PYMB_HUB_BITMAP_BYTES; i++) {
        wanted[i] = data[(i * 7) % size];
    }
    memset(&rq, 0, sizeof rq);
    rq.regs = regs;
    rq.channels = channels;
    rq.humidity_tenths = (data[0] & 0x80) ? NULL : tenths;
    rq.wanted = (data[0] & 0x40) ? wanted : NULL;
    rq.read_mask = mask;
    rq.unsupported = ~mask & 0x7Fu;
    rq.values = values;
    rq.states = states;
    rq.out_len = (size_t)PYMB_HUB_BLOCKS * channels;
    /* The request holds PYMB_HUB_REGISTERS registers: shorter inputs are the
     * caller's mistake that the struct's contract rules out. */
    if (nregs >= PYMB_HUB_REGISTERS && pymb_hub_decode(&rq) == 0) {
        for (i = 0; i < (size_t)PYMB_HUB_BLOCKS * channels; i++) {
            /* Invariants: a value iff state VALUE; states in range. */
            if (states[i] > PYMB_NOT_READ || (states[i] == PYMB_VALUE) == isnan(values[i])) {
                abort();
            }
        }
    }
    for (i = 0; i < nregs; i++) {
        double v;
        int st = pymb_hub_decode_one((pymb_hub_block)((int)(i % 9) - 1), regs[i], (int)(i & 1), &v);
        if (st > PYMB_NO_SENSOR || (st == PYMB_VALUE && isnan(v))) {
            abort();
        }
    }
    pymb_coolpro_decode_telemetry(regs, nregs, &t);
    pymb_coolpro_decode_identity(regs, nregs, &id);
out:
    free(regs);
    free(tenths);
    free(wanted);
    free(values);
    free(states);
    return 0;
}
