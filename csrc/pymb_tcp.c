/* SPDX-License-Identifier: MIT */
/*
 * pymb_tcp.c - the Modbus TCP transport ([MB-TCP]): an MBAP header with a
 * per-line transaction id (libmodbus 3.1.6 sends id 0 on raw requests), the
 * reply taken only when its transaction id, protocol id (0), length and unit
 * id match; replies to older transactions are read and dropped.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <unistd.h>

#include "pymb_internal.h"
#include "pymb_master.h"

/* Complete replies to earlier transactions are dropped by their id as they
 * are read, so pending input is kept; an owed window (after a frame cut
 * short) is paid whatever the address. */
static int tcp_prepare(pymb_line *line, int slave)
{
    (void)slave;
    return line->owed ? pymbi_pay_owed(line) : 0;
}

int pymbi_mbap_build(pymb_line *line, const uint8_t *req, int req_len, uint8_t *adu, int cap)
{
    (void)cap;
    line->tid = (uint16_t)(line->tid + 1u);
    return pymbi_mbap_frame(line->tid, req[0], req + 1, (size_t)req_len - 1, adu);
}

static int tcp_send(pymb_line *line, const uint8_t *adu, int len)
{
    return pymbi_send_all(line, adu, (size_t)len);
}

/* [MB-TCP] 3.1.3: the one MBAP length rule (pymb_frame.c). */
int pymbi_mbap_reply_length(const uint8_t *adu, int have, int expect)
{
    (void)expect;
    return have < 0 ? PYMB_FRAME_INCOMPLETE : pymbi_mbap_length(adu, (size_t)have);
}

/* Read exactly n bytes into buf before `deadline`. Returns n, or -1 and
 * errno; *got says how many arrived (a partial frame desynchronises). */
static int read_exact(pymb_line *line, int fd, uint8_t *buf, int n, uint64_t deadline, int *got)
{
    *got = 0;
    while (*got < n) {
        uint64_t now = pymbi_now_us();
        ssize_t k;
        int rc;

        if (now >= deadline) {
            errno = ETIMEDOUT;
            return -1;
        }
        rc = pymbi_wait_readable(line, fd, deadline - now);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            continue;
        }
        k = pymbi_read(line, fd, buf + *got, (size_t)(n - *got));
        if (k < 0) {
            if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) {
                continue;
            }
            return -1;
        }
        if (k == 0) {
            errno = ECONNRESET;
            return -1;
        }
        *got += (int)k;
    }
    return n;
}

/* Receive the reply to transaction line->tid: frames for other transactions
 * are read and dropped, and the wait goes on until the deadline. A frame cut
 * short (a timeout or an interrupt mid-frame, an impossible MBAP header)
 * leaves the stream out of step: the line then owes a quiet window, and the
 * failure notes the bytes that came (else the last frame dropped). */
static int tcp_receive(pymb_line *line, const uint8_t *req, int req_len, int expect,
                       uint64_t sent_us, uint8_t *rsp, int cap, pymb_failure *fail)
{
    int fd = modbus_get_socket(line->ctx), got = 0;
    uint64_t deadline = pymbi_now_us() + pymbi_timeout_us(line->ctx, 0);

    (void)req_len;
    (void)sent_us;
    (void)cap; /* >= MODBUS_MAX_ADU_LENGTH: 6 + the longest length */
    for (;;) {
        int n;

        if (read_exact(line, fd, rsp, PYMB_MBAP_LENGTH, deadline, &got) < 0) {
            if (got > 0) {
                pymbi_note_reply(fail, rsp, got, PYMB_FRAME_INCOMPLETE);
                pymbi_owe(line, req[0]);
            }
            return -1;
        }
        n = pymbi_mbap_reply_length(rsp, PYMB_MBAP_LENGTH, expect);
        if (n < 0) {
            pymbi_note_reply(fail, rsp, PYMB_MBAP_LENGTH, n);
            pymbi_owe(line, req[0]);
            errno = EMBBADDATA;
            return -1;
        }
        if (read_exact(line, fd, rsp + PYMB_MBAP_LENGTH, n - PYMB_MBAP_LENGTH, deadline, &got) <
            0) {
            pymbi_note_reply(fail, rsp, PYMB_MBAP_LENGTH + got, PYMB_FRAME_INCOMPLETE);
            pymbi_owe(line, req[0]);
            return -1;
        }
        if (((unsigned)rsp[0] << 8 | rsp[1]) == line->tid) {
            return n;
        }
        /* A reply to an earlier (timed-out) transaction: drop it, wait on
         * (a timeout then shows it: a device may not echo the id). */
        pymbi_note_reply(fail, rsp, n, PYMB_FRAME_BAD_TID);
    }
}

int pymbi_mbap_check(pymb_line *line, const uint8_t *req, int req_len, const uint8_t *rsp, int n,
                     int expect, int *exc)
{
    (void)line;
    (void)expect;
    return pymbi_tcp_check(req[0], req + 1, (size_t)req_len - 1, rsp, (size_t)n, exc);
}

/* The MBAP length delimited the frame, so the stream is in step (later
 * frames are sorted by transaction id) unless bytes already wait behind it
 * (a length that lied). */
static int tcp_lost_step(pymb_line *line)
{
    return pymbi_input_pending(line);
}

const pymb_transport pymbi_transport_tcp = {
    PYMB_FRAMING_TCP,
    PYMB_MBAP_LENGTH, /* modbus_new_tcp's context */
    PYMB_MBAP_LENGTH,
    0,
    0,
    0,
    tcp_prepare,
    pymbi_mbap_build,
    tcp_send,
    pymbi_no_flush,
    pymbi_mbap_reply_length,
    tcp_receive,
    pymbi_mbap_check,
    tcp_lost_step,
    pymbi_modbus_connect,
    pymbi_modbus_close,
};
