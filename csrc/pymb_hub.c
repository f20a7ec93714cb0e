/* SPDX-License-Identifier: MIT */
/*
 * pymb_hub.c - the sensor hub's sweep: planned block reads over libmodbus,
 * firmware fallback, busy retry, and decoding, in one call.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <string.h>
#include <time.h>

#include "pymb_internal.h"

#define FIRST PYMB_HUB_FIRST_REGISTER
#define LAST (PYMB_HUB_FIRST_REGISTER + PYMB_HUB_REGISTERS - 1)

static int bit(const uint8_t *map, unsigned i)
{
    return (map[i / 8] >> (i % 8)) & 1u;
}

static void set_bits(uint8_t *map, unsigned from, unsigned n)
{
    unsigned i;
    for (i = from; i < from + n; i++) {
        map[i / 8] = (uint8_t)(map[i / 8] | (1u << (i % 8)));
    }
}

int pymb_hub_plan_all(unsigned skip_mask, unsigned channels, pymb_span *spans, int cap)
{
    int n = 0;
    unsigned b = 0;

    if (spans == NULL || cap < 0 || channels < 1 || channels > PYMB_HUB_CHANNELS) {
        errno = EINVAL;
        return -1;
    }
    while (b < PYMB_HUB_BLOCKS) {
        unsigned start, end;

        if (skip_mask & (1u << b)) {
            b++;
            continue;
        }
        /* A run of wanted registers: whole blocks merge only when every
         * channel is read, as then the blocks are contiguous on the wire. */
        start = FIRST + b * PYMB_HUB_CHANNELS;
        end = start + channels;
        b++;
        while (channels == PYMB_HUB_CHANNELS && b < PYMB_HUB_BLOCKS &&
               !(skip_mask & (1u << b))) {
            end += PYMB_HUB_CHANNELS;
            b++;
        }
        while (start < end) {
            unsigned count = end - start > PYMB_MAX_READ_REGISTERS ? PYMB_MAX_READ_REGISTERS
                                                                  : end - start;
            if (n >= cap) {
                errno = EINVAL;
                return -1;
            }
            spans[n].address = (uint16_t)start;
            spans[n].count = (uint16_t)count;
            n++;
            start += count;
        }
    }
    return n;
}

static void pause_us(uint32_t us)
{
    struct timespec ts;
    ts.tv_sec = (time_t)(us / 1000000u);
    ts.tv_nsec = (long)(us % 1000000u) * 1000L;
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

/* One span, with the hub's busy answer retried. */
static int read_span(pymb_line *line, const pymb_hub_request *rq, unsigned address,
                     unsigned count, pymb_failure *fail)
{
    uint32_t wait = rq->options.busy_backoff_us;
    int tries = 0;

    for (;;) {
        if (pymb_read_registers(line, MODBUS_FC_READ_HOLDING_REGISTERS, rq->slave, (int)address,
                                (int)count, rq->regs + (address - FIRST), fail) == (int)count) {
            return 0;
        }
        if (errno != EMBXSFAIL || tries >= rq->options.busy_retries) {
            return -1;
        }
        tries++;
        pause_us(wait);
        if (wait <= UINT32_MAX / 2) {
            wait *= 2;
        }
    }
}

/* After exception 02 on a span: read it again block by block, each block's
 * wanted registers in runs; a block answered 02 on its own is missing. */
static int read_by_block(pymb_line *line, pymb_hub_request *rq, const pymb_span *sp,
                         uint8_t *covered, pymb_failure *fail)
{
    unsigned from = sp->address, to = sp->address + sp->count; /* [from, to) */
    unsigned b;

    for (b = (from - FIRST) / PYMB_HUB_CHANNELS; b < PYMB_HUB_BLOCKS; b++) {
        unsigned lo = FIRST + b * PYMB_HUB_CHANNELS, hi = lo + PYMB_HUB_CHANNELS;
        unsigned a;

        if (lo >= to) {
            break;
        }
        if (lo < from) {
            lo = from;
        }
        if (hi > to) {
            hi = to;
        }
        if (rq->unsupported & (1u << b)) {
            continue;
        }
        a = lo;
        while (a < hi) {
            unsigned end;

            if (rq->wanted != NULL && !bit(rq->wanted, a - FIRST)) {
                a++;
                continue;
            }
            end = a + 1;
            while (end < hi && (rq->wanted == NULL || bit(rq->wanted, end - FIRST))) {
                end++;
            }
            if (read_span(line, rq, a, end - a, fail) == 0) {
                set_bits(covered, a - FIRST, end - a);
            } else if (errno == EMBXILADD) {
                rq->unsupported |= 1u << b;
                break;
            } else {
                return -1;
            }
            a = end;
        }
    }
    return 0;
}

int pymb_hub_read(pymb_line *line, pymb_hub_request *rq, pymb_failure *fail)
{
    uint8_t covered[PYMB_HUB_BITMAP_BYTES];
    uint8_t asked[PYMB_HUB_BITMAP_BYTES];
    unsigned b, i;
    int k;

    pymb_failure_reset(fail);
    if (rq != NULL) {
        rq->read_mask = 0;
    }
    if (line == NULL || rq == NULL || rq->regs == NULL || rq->spans == NULL ||
        rq->nspans < 0 || rq->channels < 1 || rq->channels > PYMB_HUB_CHANNELS ||
        rq->slave < 1 || rq->slave > 255 || rq->options.busy_retries < 0 ||
        (rq->values != NULL &&
         (rq->states == NULL || rq->out_len < (size_t)PYMB_HUB_BLOCKS * rq->channels))) {
        errno = EINVAL;
        return -1;
    }
    for (k = 0; k < rq->nspans; k++) {
        const pymb_span *sp = &rq->spans[k];
        if (sp->count < 1 || sp->address < FIRST ||
            (unsigned)sp->address + sp->count - 1 > LAST) {
            errno = EINVAL;
            return -1;
        }
    }
    memset(covered, 0, sizeof covered);
    memset(asked, 0, sizeof asked);
    rq->read_mask = 0;

    for (k = 0; k < rq->nspans; k++) {
        const pymb_span *sp = &rq->spans[k];

        set_bits(asked, sp->address - FIRST, sp->count);
        if (read_span(line, rq, sp->address, sp->count, fail) == 0) {
            set_bits(covered, sp->address - FIRST, sp->count);
        } else if (errno != EMBXILADD || read_by_block(line, rq, sp, covered, fail) < 0) {
            return -1;
        }
    }

    /* A block is read when every register asked of it (and wanted) arrived. */
    for (b = 0; b < PYMB_HUB_BLOCKS; b++) {
        int any = 0, all = 1;
        for (i = b * PYMB_HUB_CHANNELS; i < (b + 1) * PYMB_HUB_CHANNELS; i++) {
            if (bit(asked, i) && (rq->wanted == NULL || bit(rq->wanted, i))) {
                any = 1;
                all = all && bit(covered, i);
            }
        }
        if (any && all && !(rq->unsupported & (1u << b))) {
            rq->read_mask |= 1u << b;
        }
    }
    if (rq->values != NULL &&
        pymb_hub_decode(rq) < 0) {
        errno = EINVAL;
        return -1;
    }
    return 0;
}
