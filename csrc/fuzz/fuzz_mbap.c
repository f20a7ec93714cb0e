/* SPDX-License-Identifier: MIT */
/*
 * fuzz_mbap.c - libFuzzer target: a pipelined poll's replies taken
 * (pymbi_mbap_take) and frames written (pymbi_mbap_frames). The input makes
 * a table of up to 8 requests (sizes and offsets that may not fit the image)
 * and a buffer of replies, each in an exactly sized heap buffer; the image
 * keeps every byte no taken reply may write.
 */
#include <stdlib.h>
#include <string.h>

#include "../pymb_mbap.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define IMAGE 64

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    pymbi_mbap_req reqs[8];
    uint8_t image[IMAGE], before[IMAGE], frames[8 * PYMBI_MBAP_FRAME];
    uint8_t *buf;
    size_t n, i, len, used = 0, pos = 0, want = 0;
    uint16_t tid;
    int got;

    if (size < 3) {
        return 0;
    }
    n = data[0] % 9;
    tid = (uint16_t)(data[1] << 8 | data[2]);
    data += 3;
    size -= 3;
    memset(reqs, 0, sizeof reqs);
    for (i = 0; i < n && size >= 4; i++) {
        reqs[i].size = (uint16_t)(data[0] % 80);
        reqs[i].offset = data[1] % (IMAGE + 8);
        reqs[i].head[0] = 0;
        reqs[i].head[1] = 0;
        reqs[i].head[2] = 0;
        reqs[i].head[3] = (uint8_t)(reqs[i].size > 6 ? reqs[i].size - 6 : 0);
        reqs[i].head[4] = data[2];
        reqs[i].head[5] = data[3];
        reqs[i].head[6] = (uint8_t)(reqs[i].size > 9 ? reqs[i].size - 9 : 0);
        data += 4;
        size -= 4;
    }
    n = i;
    len = size;
    buf = malloc(len ? len : 1);
    if (buf == NULL) {
        return 0;
    }
    memcpy(buf, data, len);
    for (i = 0; i < IMAGE; i++) {
        image[i] = before[i] = (uint8_t)(0xA5 ^ i);
    }
    got = pymbi_mbap_take(reqs, n, 0, n, tid, buf, len, image, IMAGE, &used);
    if (got > (int)n || got < -1) {
        abort();
    }
    if (got == -1 && memcmp(image, before, IMAGE) != 0) {
        abort(); /* a table that does not fit writes nothing */
    }
    for (i = 0; got > 0 && i < (size_t)got; i++) {
        const pymbi_mbap_req *r = &reqs[i];
        if (memcmp(buf + pos + 2, r->head, sizeof r->head) != 0 ||
            buf[pos] != (uint8_t)((uint16_t)(tid + i) >> 8) ||
            buf[pos + 1] != (uint8_t)(tid + i)) {
            abort(); /* took a reply that is not the one expected */
        }
        memcpy(before + r->offset, buf + pos + PYMBI_MBAP_HEAD, r->size - PYMBI_MBAP_HEAD);
        pos += r->size;
        want += r->size;
    }
    if (got >= 0 && (used != want || used > len || memcmp(image, before, IMAGE) != 0)) {
        abort(); /* only the taken replies' data, each at its place */
    }
    got = pymbi_mbap_frames(reqs, n, 0, n, tid, frames, sizeof frames);
    if (got != (int)(n * PYMBI_MBAP_FRAME)) {
        abort();
    }
    free(buf);
    return 0;
}
