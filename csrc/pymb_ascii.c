/* SPDX-License-Identifier: MIT */
/*
 * pymb_ascii.c - the Modbus ASCII transport on a serial line ([MB-SL] 2.5.2):
 * ':', address + PDU + LRC as two hexadecimal characters per byte, CR LF.
 * libmodbus opens and sets up the port (an RTU context: it has no ASCII
 * transport); pymb frames, sends, receives and checks. A gap longer than the
 * inter-character timeout (the context's byte timeout, PYMB_ASCII_CHAR_US
 * when that is 0) drops the frame begun. As on RTU, a failure owes a quiet
 * window, so a late reply is never taken as a later request's answer.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <string.h>
#include <unistd.h>

#include "pymb_internal.h"

static const char hex_digits[] = "0123456789ABCDEF";

uint8_t pymbi_ascii_lrc(const uint8_t *b, size_t n)
{
    unsigned sum = 0;
    size_t i;

    for (i = 0; i < n; i++) {
        sum += b[i];
    }
    return (uint8_t)(0u - sum);
}

int pymbi_ascii_encode(const uint8_t *b, int n, uint8_t *out, int cap)
{
    int i, k = 0;
    uint8_t lrc;

    if (b == NULL || out == NULL || n < 2 || n > 1 + PYMB_MAX_PDU || cap < 1 + 2 * (n + 1) + 2) {
        return -1;
    }
    lrc = pymbi_ascii_lrc(b, (size_t)n);
    out[k++] = ':';
    for (i = 0; i <= n; i++) {
        uint8_t v = i < n ? b[i] : lrc;
        out[k++] = (uint8_t)hex_digits[v >> 4];
        out[k++] = (uint8_t)hex_digits[v & 0x0Fu];
    }
    out[k++] = '\r';
    out[k++] = '\n';
    return k;
}

/* The value of a hexadecimal digit (either case), -1 for any other. */
static int hex_value(uint8_t c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    return -1;
}

int pymbi_ascii_feed(pymbi_ascii_rx *rx, uint8_t c)
{
    int v;

    if (c == ':') {
        memset(rx, 0, sizeof *rx);
        rx->in_frame = 1;
        return PYMB_FRAME_INCOMPLETE;
    }
    if (!rx->in_frame) {
        return PYMB_FRAME_INCOMPLETE; /* noise between frames */
    }
    if (rx->cr) {
        int n = rx->nhex / 2;
        rx->in_frame = 0;
        rx->cr = 0;
        if (c != '\n' || rx->bad || rx->nhex % 2 != 0) {
            return PYMB_FRAME_BAD_TEXT; /* (CR not followed by LF) */
        }
        return n < 3 ? PYMB_FRAME_BAD_LENGTH : n;
    }
    if (c == '\r') {
        rx->cr = 1;
        return PYMB_FRAME_INCOMPLETE;
    }
    v = hex_value(c);
    if (v < 0) {
        rx->bad = 1; /* the frame is kept to its end, then refused whole */
        return PYMB_FRAME_INCOMPLETE;
    }
    if (rx->bad) {
        return PYMB_FRAME_INCOMPLETE; /* out holds the bytes before the bad character */
    }
    if (rx->nhex >= 2 * PYMB_ASCII_MAX_BYTES) {
        rx->in_frame = 0;
        return PYMB_FRAME_TOO_LONG;
    }
    if (rx->nhex % 2 == 0) {
        rx->out[rx->nhex / 2] = (uint8_t)(v << 4);
    } else {
        rx->out[rx->nhex / 2] |= (uint8_t)v;
    }
    rx->nhex++;
    return PYMB_FRAME_INCOMPLETE;
}

int pymbi_ascii_check(const uint8_t *req, int req_len, const uint8_t *f, int n, int *exc)
{
    if (req == NULL || f == NULL || req_len < 2 || n < 3) {
        return PYMB_FRAME_INVALID;
    }
    if (pymbi_ascii_lrc(f, (size_t)(n - 1)) != f[n - 1]) {
        return PYMB_FRAME_BAD_CRC;
    }
    if (f[0] != req[0]) {
        return PYMB_FRAME_BAD_SLAVE;
    }
    return pymb_check_response_pdu(req + 1, (size_t)req_len - 1, f + 1, (size_t)(n - 2), exc);
}

static int ascii_build(pymb_line *line, const uint8_t *req, int req_len, uint8_t *adu, int cap)
{
    (void)line;
    return pymbi_ascii_encode(req, req_len, adu, cap);
}

static int ascii_send(pymb_line *line, const uint8_t *adu, int len)
{
    return pymbi_write_all(line, adu, (size_t)len);
}

/* Frames are delimited by their characters, not by a length. */
static int ascii_reply_length(const uint8_t *adu, int have, int expect)
{
    (void)adu;
    (void)have;
    (void)expect;
    return PYMB_FRAME_BAD_FUNCTION;
}

/* A whole frame with a good LRC from the address whose request failed,
 * while its quiet window runs: its late reply, dropped. */
static int late_frame(const pymb_line *line, int slave, const uint8_t *f, int n)
{
    return line->owed && f[0] == line->owed_slave && f[0] != slave &&
           pymbi_ascii_lrc(f, (size_t)(n - 1)) == f[n - 1];
}

/* Receive one frame before the response timeout: characters before a ':'
 * are dropped, and so is a frame whose characters stop for longer than the
 * inter-character timeout (the wait goes on for a whole frame; a timeout
 * then notes what that frame had). A frame ended by CR LF that is no frame
 * (garbled, too short) or one longer than any frame fails the request at
 * once, as a bad LRC does ([MB-SL] 2.4.1: an error detected on the frame).
 * The decoded bytes (address, PDU, LRC) go to rsp. */
static int ascii_receive(pymb_line *line, const uint8_t *req, int req_len, int expect,
                         uint64_t sent_us, uint8_t *rsp, int cap, pymb_failure *fail)
{
    int fd = modbus_get_socket(line->ctx);
    uint64_t deadline = pymbi_now_us() + pymbi_timeout_us(line->ctx, 0);
    uint64_t char_us = pymbi_timeout_us(line->ctx, 1), last = 0;
    pymbi_ascii_rx rx;
    uint8_t buf[128];
    int gone = -1; /* the bytes of the last frame a gap dropped, in rsp (-1: none) */

    (void)req_len;
    (void)expect;
    (void)sent_us;
    if (char_us == 0) {
        char_us = PYMB_ASCII_CHAR_US;
    }
    memset(&rx, 0, sizeof rx);
    for (;;) {
        uint64_t now = pymbi_now_us(), wait;
        ssize_t k;
        ssize_t i;
        int rc;

        if (rx.in_frame && now - last >= char_us) {
            /* [MB-SL] 2.5.2.1: too long a gap drops the frame (kept for the note) */
            gone = rx.nhex / 2 < cap ? rx.nhex / 2 : cap;
            memcpy(rsp, rx.out, (size_t)gone);
            memset(&rx, 0, sizeof rx);
        }
        if (now >= deadline) {
            if (rx.in_frame) {
                pymbi_note_reply(fail, rx.out, rx.nhex / 2, PYMB_FRAME_INCOMPLETE);
            } else if (gone >= 0) {
                pymbi_note_reply(fail, rsp, gone, PYMB_FRAME_INCOMPLETE);
            }
            pymbi_owe(line, req[0]);
            errno = ETIMEDOUT;
            return -1;
        }
        wait = deadline - now;
        if (rx.in_frame && last + char_us - now < wait) {
            wait = last + char_us - now;
        }
        rc = pymbi_wait_readable(line, fd, wait);
        if (rc < 0) {
            pymbi_owe(line, req[0]);
            return -1;
        }
        if (rc == 0) {
            continue;
        }
        k = read(fd, buf, sizeof buf);
        if (k < 0) {
            if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) {
                continue;
            }
            pymbi_owe(line, req[0]);
            return -1;
        }
        if (k == 0) {
            pymbi_owe(line, req[0]);
            errno = ECONNRESET;
            return -1;
        }
        last = pymbi_now_us();
        for (i = 0; i < k; i++) {
            int n = pymbi_ascii_feed(&rx, buf[i]);
            if (n == PYMB_FRAME_INCOMPLETE) {
                continue;
            }
            if (n < 0) {
                /* A frame that is no frame, or one too long: the request
                 * fails, and the line owes a quiet window as after any bad
                 * frame (the rest of this one, or the answer, may come). */
                pymbi_note_reply(fail, rx.out, rx.nhex / 2, n);
                pymbi_owe(line, req[0]);
                errno = EMBBADDATA;
                return -1;
            }
            if (n > cap) {
                n = cap; /* cannot happen: cap >= MODBUS_MAX_ADU_LENGTH */
            }
            if (late_frame(line, req[0], rx.out, n)) {
                continue;
            }
            memcpy(rsp, rx.out, (size_t)n);
            return n;
        }
    }
}

static int ascii_check(pymb_line *line, const uint8_t *req, int req_len, const uint8_t *rsp,
                       int n, int expect, int *exc)
{
    (void)line;
    (void)expect;
    return pymbi_ascii_check(req, req_len, rsp, n, exc);
}

const pymb_transport pymbi_transport_ascii = {
    PYMB_FRAMING_ASCII,
    1, /* modbus_new_rtu's context */
    1,
    1, /* the LRC */
    1,
    1,
    pymbi_rtu_prepare,
    ascii_build,
    ascii_send,
    pymbi_serial_flush,
    ascii_reply_length,
    ascii_receive,
    ascii_check,
    pymbi_rtu_lost_step, /* a frame that failed its check may not have been the answer */
    pymbi_modbus_connect,
    pymbi_modbus_close,
};
