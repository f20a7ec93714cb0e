/* SPDX-License-Identifier: MIT */
/*
 * fuzz_master.c - libFuzzer target: arbitrary bytes taken by the sans-I/O
 * TCP master (pymbi_master_take, or pymbi_master_step, which frames the
 * reads again when a take ends the poll). The input's first bytes make up to 8
 * reads (functions 1..4, counts and offsets that may not fit the image:
 * those are refused) framed from a first transaction id; the rest is fed in
 * pieces whose sizes the input also says, each in an exactly sized heap
 * buffer. Checks: no byte of the image outside a framed read's place is
 * written, the counts stay consistent, every byte is taken or the take
 * stopped for a reason, a step frames the reads again only after a take that
 * ended the poll. And the clean-stream rule (pymbi_mbap_clean) over the input.
 */
#include <stdlib.h>
#include <string.h>

#include "../pymb.h"
#include "../pymb_master.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define IMAGE 96

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static pymbi_master m;
    pymbi_mreq reqs[8];
    uint8_t image[IMAGE + 16], frames[8 * PYMBI_MASTER_FRAME], owned[IMAGE];
    pymbi_mevent ev[4];
    size_t n, i, pos, k, nreq;

    /* the clean-stream rule: what an exception or a bad header made unclean
     * stays so with more bytes */
    if (!pymbi_mbap_clean(data, size / 2) && pymbi_mbap_clean(data, size)) {
        abort();
    }
    if (size < 3) {
        return 0;
    }
    n = data[0] % 9;
    pymbi_master_reset(&m, (uint16_t)(data[1] << 8 | data[2]));
    pos = 3;
    memset(owned, 0, sizeof owned);
    memset(image, 0xA5, sizeof image);
    for (i = 0; i < n && size - pos >= 4; i++, pos += 4) {
        pymbi_mreq *r = &reqs[i];
        memset(r, 0, sizeof *r);
        r->unit = data[pos] & 3;
        r->function = (uint8_t)(1 + (data[pos] >> 2) % 5); /* 5: not a read */
        r->address = data[pos + 1];
        r->count = data[pos + 2] % 64;
        r->offset = data[pos + 3] % (IMAGE + 8);
        r->token = (uint32_t)i;
        r->flags = (uint8_t)(data[pos + 2] >> 7); /* PYMBI_MREQ_PACKED or not */
        if (pymbi_master_frames(&m, r, 1, IMAGE, frames, sizeof frames) == PYMBI_MASTER_FRAME) {
            size_t nb = r->function <= 2 && r->flags ? (r->count + 7u) / 8u : 2u * r->count;
            for (k = 0; k < nb; k++) {
                owned[r->offset + k] = 1; /* (frames checked it fits) */
            }
        }
    }
    nreq = i;
    while (pos < size) {
        int step = data[pos] >> 7;
        size_t piece = 1 + data[pos++] % 32, used = 0, framed = 0;
        uint8_t *buf;
        int got;

        if (piece > size - pos) {
            piece = size - pos;
        }
        buf = malloc(piece ? piece : 1);
        if (buf == NULL) {
            return 0;
        }
        memcpy(buf, data + pos, piece);
        if (step) {
            got = pymbi_master_step(&m, buf, piece, image, IMAGE, ev, 4, &used, reqs, nreq,
                                    frames, sizeof frames, &framed);
        } else {
            got = pymbi_master_take(&m, buf, piece, image, IMAGE, ev, 4, &used);
        }
        free(buf);
        if (got < 0 || got > 4 || used > piece) {
            abort();
        }
        if (framed != 0 && (got != 0 || used != piece || framed != nreq * PYMBI_MASTER_FRAME ||
                            m.in_flight != nreq || m.part_len != 0)) {
            abort(); /* framed again only after a take that ended the poll */
        }
        if (m.in_flight > m.span || m.span > PYMBI_MASTER_INFLIGHT ||
            m.part_len >= PYMBI_MASTER_ADU || m.bad_len > PYMBI_MASTER_ADU) {
            abort();
        }
        if (used < piece && got < 4 && !m.broken) {
            abort(); /* stopped with room for events and no bad frame */
        }
        for (k = 0; k < (size_t)got; k++) {
            if (ev[k].kind < PYMBI_EV_EXCEPTION || ev[k].kind > PYMBI_EV_BAD ||
                (ev[k].token != PYMBI_NO_TOKEN && ev[k].token >= n)) {
                abort();
            }
        }
        pos += used ? used : piece; /* (a broken stream: the rest is skipped) */
        if (m.broken) {
            break;
        }
    }
    for (k = 0; k < IMAGE; k++) {
        if (!owned[k] && image[k] != 0xA5) {
            abort();
        }
    }
    for (k = IMAGE; k < sizeof image; k++) {
        if (image[k] != 0xA5) {
            abort();
        }
    }
    (void)pymbi_master_pending(&m, NULL, 0);
    return 0;
}
