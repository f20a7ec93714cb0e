/* SPDX-License-Identifier: MIT */
/*
 * pymb_mbap.c - a pipelined Modbus TCP poll's requests written and its
 * replies taken, many per call (see pymb_mbap.h). No allocation, no I/O, no
 * state between calls.
 */
#include <errno.h>
#include <string.h>

#include "pymb_mbap.h"

int pymbi_mbap_frames(const pymbi_mbap_req *reqs, size_t nreqs, size_t first, size_t n,
                      uint16_t tid, uint8_t *out, size_t out_cap)
{
    size_t i;
    if (reqs == NULL || out == NULL || first > nreqs || n > nreqs - first ||
        n > out_cap / PYMBI_MBAP_FRAME) {
        errno = EINVAL;
        return -1;
    }
    for (i = 0; i < n; i++, tid++) {
        uint8_t *f = out + i * PYMBI_MBAP_FRAME;
        f[0] = (uint8_t)(tid >> 8);
        f[1] = (uint8_t)(tid & 0xFF);
        memcpy(f + 2, reqs[first + i].tail, sizeof reqs[first + i].tail);
    }
    return (int)(n * PYMBI_MBAP_FRAME);
}

int pymbi_mbap_take(const pymbi_mbap_req *reqs, size_t nreqs, size_t first, size_t n,
                    uint16_t tid, const uint8_t *buf, size_t len, uint8_t *image,
                    size_t image_len, size_t *used)
{
    size_t i, pos = 0;
    if (reqs == NULL || used == NULL || (buf == NULL && len > 0) || first > nreqs ||
        n > nreqs - first) {
        errno = EINVAL;
        return -1;
    }
    for (i = first; i < first + n; i++) {
        const pymbi_mbap_req *r = &reqs[i];
        if (r->size < PYMBI_MBAP_HEAD || image == NULL ||
            r->offset > image_len ||
            (size_t)r->size - PYMBI_MBAP_HEAD > image_len - r->offset) {
            errno = EINVAL;
            return -1;
        }
    }
    *used = 0;
    for (i = 0; i < n; i++, tid++) {
        const pymbi_mbap_req *r = &reqs[first + i];
        const uint8_t *p = buf + pos;
        if (len - pos < r->size || p[0] != (uint8_t)(tid >> 8) ||
            p[1] != (uint8_t)(tid & 0xFF) || memcmp(p + 2, r->head, sizeof r->head) != 0)
            break;
        memcpy(image + r->offset, p + PYMBI_MBAP_HEAD, (size_t)r->size - PYMBI_MBAP_HEAD);
        pos += r->size;
    }
    *used = pos;
    return (int)i;
}
