/* SPDX-License-Identifier: MIT */
/*
 * fuzz_serve.c - libFuzzer target: a client's bytes taken as Modbus TCP
 * requests (pymbi_srv_take) one frame after another, each answered
 * (pymbi_srv_exception or pymbi_srv_reply with the request's own PDU), as
 * pymb serve does. The input is copied into an exactly sized heap buffer,
 * so a read past its end is caught; every frame taken must lie inside it and
 * agree with its own header.
 */
#include <stdlib.h>
#include <string.h>

#include "../pymb_serve.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    uint8_t *buf = malloc(size ? size : 1);
    uint8_t out[PYMBI_SRV_MAX_FRAME];
    size_t pos = 0;
    pymbi_srv_req r;

    if (buf == NULL)
        return 0;
    memcpy(buf, data, size);
    for (;;) {
        int n = pymbi_srv_take(buf + pos, size - pos, &r);
        if (n <= 0)
            break;
        if ((size_t)n > size - pos || (size_t)n != PYMBI_SRV_MBAP + r.pdu_len - 1 + 1 ||
            r.pdu_len < 1 || r.pdu_len > PYMBI_SRV_MAX_PDU || r.function != buf[pos + 7] ||
            r.exception > 3)
            abort();
        if (r.exception) {
            if (pymbi_srv_exception(r.tid, r.unit, r.function, r.exception, out, sizeof out) != 9)
                abort();
        } else if (pymbi_srv_reply(r.tid, r.unit, buf + pos + PYMBI_SRV_MBAP, r.pdu_len, out,
                                   sizeof out) != n) {
            abort();
        }
        pos += (size_t)n;
    }
    free(buf);
    return 0;
}
