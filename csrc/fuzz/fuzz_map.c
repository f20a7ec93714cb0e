/* SPDX-License-Identifier: MIT */
/*
 * fuzz_map.c - libFuzzer target: pymb_map_decode on arbitrary tables and
 * registers. The input's first byte says how many entries follow (0..7), each
 * built from 24 bytes (type, count, first, channels, stride, order, bit,
 * width, flags, decimals, markers, out, aux: valid or not), then two markers,
 * then the registers, copied into exactly sized heap buffers so that
 * AddressSanitizer sees any access outside them. Scale and offset are the
 * finite, nonzero values a map file may give. The same arguments made ready
 * (pymbi_map_ready, pymbi_map_run) must be refused or accepted alike and
 * write the same values and states.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../pymb.h"
#include "../pymb_map_ready.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define ENTRY_BYTES 24
#define SLOTS 64
#define TEXT 64

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const double scales[4] = {0.1, 0.001, 2.5, -1.0 / 3.0};
    size_t n, i, nregs, at;
    pymb_map_entry *e = NULL;
    pymb_map_marker mk[2];
    uint16_t *regs = NULL;
    double *values = NULL;
    int64_t *ints = NULL;
    uint8_t *states = NULL, *text = NULL;
    pymb_map_out out;
    pymbi_map_job job;
    double *first_values = NULL;
    uint8_t *first_states = NULL;
    int rc;

    if (size < 1) {
        return 0;
    }
    n = data[0] % 8;
    at = 1;
    if (size < at + n * ENTRY_BYTES + 2 * 3) {
        return 0;
    }
    e = calloc(n ? n : 1, sizeof *e);
    if (e == NULL) {
        return 0;
    }
    for (i = 0; i < n; i++, at += ENTRY_BYTES) {
        const uint8_t *d = data + at;
        e[i].type = d[0] % (PYMB_MAP_TYPES + 1);
        e[i].count = d[1] % 9;
        e[i].first = d[2] % 40;
        e[i].channels = d[3] % 6;
        e[i].stride = d[4] % 5;
        memcpy(e[i].order, d + 5, PYMB_MAP_MAX_BYTES);
        for (size_t k = 0; k < PYMB_MAP_MAX_BYTES; k++) {
            e[i].order[k] %= 9;
        }
        e[i].bit = d[13] % 70;
        e[i].width = d[14] % 70;
        e[i].flags = d[15];
        e[i].decimals = d[16] % 24;
        e[i].first_marker = d[17] % 3;
        e[i].nmarkers = d[18] % 3;
        e[i].out = d[19] % SLOTS;
        e[i].aux = d[20] % TEXT | ((d[13] & 0x80) ? PYMB_MAP_SF_SWAPPED : 0u);
        e[i].scale = scales[d[21] % 4];
        e[i].offset = (double)(int8_t)d[22];
    }
    for (i = 0; i < 2; i++, at += 3) {
        mk[i].raw = (uint64_t)(data[at] << 8 | data[at + 1]);
        mk[i].state = (uint8_t)(data[at + 2] % 5 == 4 ? PYMB_MAP_MARKER_MASK
                                                       : 16 + data[at + 2] % 5);
    }
    nregs = (size - at) / 2;
    regs = malloc((nregs ? nregs : 1) * sizeof *regs);
    values = malloc(SLOTS * sizeof *values);
    ints = malloc(SLOTS * sizeof *ints);
    states = malloc(SLOTS);
    text = malloc(TEXT);
    first_values = malloc(SLOTS * sizeof *first_values);
    first_states = malloc(SLOTS);
    if (!regs || !values || !ints || !states || !text || !first_values || !first_states) {
        goto out;
    }
    for (i = 0; i < nregs; i++) {
        regs[i] = (uint16_t)(data[at + 2 * i] << 8 | data[at + 2 * i + 1]);
    }
    memset(states, 0xAA, SLOTS);
    out.values = values;
    out.ints = (data[0] & 0x80) ? NULL : ints;
    out.states = states;
    out.len = SLOTS;
    out.text = text;
    out.text_len = TEXT;
    rc = pymb_map_decode(e, n, mk, 2, regs, nregs, &out);
    if (rc >= 0) {
        for (i = 0; i < n; i++) {
            for (size_t c = 0; c < e[i].channels; c++) {
                size_t s = e[i].out + c;
                uint8_t st = states[s];
                /* a known state; no value unless the state says so */
                if (!(st == PYMB_VALUE || st == PYMB_MAP_NAN || st == PYMB_MAP_INVALID_TEXT ||
                      st == PYMB_MAP_NO_SCALE || (st >= 16 && st < 20))) {
                    abort();
                }
                if (st != PYMB_VALUE && !isnan(values[s])) {
                    abort();
                }
            }
        }
    }
    memcpy(first_values, values, SLOTS * sizeof *values);
    memcpy(first_states, states, SLOTS);
    memset(&job, 0, sizeof job);
    if (pymbi_map_run(&job) != -1) { /* a zeroed job is not ready */
        abort();
    }
    job.entries = e;
    job.nentries = n;
    job.markers = mk;
    job.nmarkers = 2;
    job.regs = regs;
    job.nregs = nregs;
    job.out = out;
    if (pymbi_map_ready(&job) != rc || (rc < 0 && pymbi_map_run(&job) != -1)) {
        abort();
    }
    if (rc >= 0) {
        memset(states, 0xAA, SLOTS);
        if (pymbi_map_run(&job) != rc || memcmp(states, first_states, SLOTS) != 0) {
            abort();
        }
        for (i = 0; i < SLOTS; i++) { /* the same bits, NaN included */
            if (memcmp(&values[i], &first_values[i], sizeof values[i]) != 0 &&
                !(isnan(values[i]) && isnan(first_values[i]))) {
                abort();
            }
        }
    }
out:
    free(e);
    free(regs);
    free(values);
    free(ints);
    free(states);
    free(text);
    free(first_values);
    free(first_states);
    return 0;
}
