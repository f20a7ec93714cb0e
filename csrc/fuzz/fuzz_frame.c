/* SPDX-License-Identifier: MIT */
/*
 * fuzz_frame.c - libFuzzer target: frame lengths and response checks.
 * The first byte splits the input into a request and a response, each
 * copied into an exactly sized heap buffer.
 */
#include <stdlib.h>
#include <string.h>

#include "../pymb.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t split, rsp_len;
    uint8_t *req, *rsp;
    int len, st, code = -1;

    if (size < 1) {
        return 0;
    }
    split = data[0] < size - 1 ? data[0] : size - 1;
    rsp_len = size - 1 - split;
    req = malloc(split ? split : 1);
    rsp = malloc(rsp_len ? rsp_len : 1);
    if (req == NULL || rsp == NULL) {
        goto out;
    }
    memcpy(req, data + 1, split);
    memcpy(rsp, data + 1 + split, rsp_len);

    len = pymb_rtu_response_length(rsp, rsp_len);
    if (len > PYMB_RTU_MAX_ADU || (len >= 0 && len < 5)) {
        abort();
    }
    len = pymb_rtu_request_length(req, split);
    if (len > PYMB_RTU_MAX_ADU || (len >= 0 && len < 4)) {
        abort();
    }
    st = pymb_rtu_check_response(req, split, rsp, rsp_len, &code);
    if (st == PYMB_FRAME_OK && !pymb_rtu_crc_ok(rsp, rsp_len)) {
        abort(); /* never accept a frame whose CRC is wrong */
    }
    if (st == PYMB_FRAME_EXCEPTION && (code < 0 || code > 255)) {
        abort();
    }
    if (split > 0 && rsp_len > 0) {
        st = pymb_check_response_pdu(req, split, rsp, rsp_len, &code);
    }
    (void)pymb_frame_strerror(st);
    (void)pymb_crc16(rsp, rsp_len);
out:
    free(req);
    free(rsp);
    return 0;
}
