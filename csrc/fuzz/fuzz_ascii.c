/* SPDX-License-Identifier: MIT */
/*
 * fuzz_ascii.c - libFuzzer target: the Modbus ASCII reply parser
 * (pymb_ascii.c). The first 6 bytes are a request (address + PDU); the rest
 * is fed to the receiver character by character, as a line would bring it.
 * Every frame it gives is checked against the request, must hold 3..255
 * bytes, and must survive encoding again and decoding to the same bytes.
 */
#include <stdlib.h>
#include <string.h>

#include "../pymb_internal.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    pymbi_ascii_rx rx, again;
    uint8_t req[6], text[PYMB_ASCII_MAX_TEXT];
    size_t i;

    if (size < sizeof req) {
        return 0;
    }
    memcpy(req, data, sizeof req);
    memset(&rx, 0, sizeof rx);
    for (i = sizeof req; i < size; i++) {
        int n = pymbi_ascii_feed(&rx, data[i]), exc = 0, st, k, j, m = PYMB_FRAME_INCOMPLETE;

        if (n == PYMB_FRAME_INCOMPLETE || n == PYMB_FRAME_BAD_LENGTH ||
            n == PYMB_FRAME_TOO_LONG || n == PYMB_FRAME_BAD_TEXT) {
            continue;
        }
        if (n < 3 || n > PYMB_ASCII_MAX_BYTES) {
            abort();
        }
        st = pymbi_ascii_check(req, (int)sizeof req, rx.out, n, &exc);
        /* (code 0 is a frame's byte too: pymb_exception_errno makes it EMBBADEXC) */
        if (st == PYMB_FRAME_EXCEPTION && (exc < 0 || exc > 255)) {
            abort();
        }
        if (st == PYMB_FRAME_OK && pymbi_ascii_lrc(rx.out, (size_t)n) != 0) {
            abort(); /* a good LRC makes the whole frame's sum 0 */
        }
        /* Encode the frame's bytes (without the LRC) again and decode. */
        k = pymbi_ascii_encode(rx.out, n - 1, text, (int)sizeof text);
        if (k != 1 + 2 * n + 2 && n - 1 <= 1 + PYMB_MAX_PDU) {
            abort();
        }
        memset(&again, 0, sizeof again);
        for (j = 0; j < k; j++) {
            m = pymbi_ascii_feed(&again, text[j]);
        }
        if (k > 0 && (m != n || memcmp(again.out, rx.out, (size_t)n - 1) != 0 ||
                      again.out[n - 1] != pymbi_ascii_lrc(rx.out, (size_t)n - 1))) {
            abort();
        }
    }
    return 0;
}
