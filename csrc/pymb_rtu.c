/* SPDX-License-Identifier: MIT */
/*
 * pymb_rtu.c - the RTU transport on a serial line: address + PDU + CRC,
 * frames ended by their length or by the line's silence. libmodbus sends
 * (it appends the CRC and drives RTS); pymb receives and checks. RTU over TCP
 * (pymb_rtu_tcp.c) shares the receiving half.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <string.h>
#include <unistd.h>

#include "pymb_internal.h"

/* Before a request: discard pending input, or, when a quiet window is owed,
 * pay it, but only for a request to the address that failed: a late reply
 * carries that address, which cannot pass as another's answer, so a request
 * to another address does not wait (pymbi_rtu_receive drops the failed
 * address's frames while the window runs), and a scan of silent addresses
 * costs one timeout each. */
int pymbi_rtu_prepare(pymb_line *line, int slave)
{
    if (!line->owed) {
        return pymb_flush(line);
    }
    if (slave != line->owed_slave) {
        if (pymbi_now_us() >= line->owed_since_us + pymbi_quiet_window_us(line)) {
            line->owed = 0;
        }
        return pymb_flush(line);
    }
    return pymbi_pay_owed(line);
}

/* libmodbus appends the CRC itself (modbus_send_raw_request). */
static int rtu_build(pymb_line *line, const uint8_t *req, int req_len, uint8_t *adu, int cap)
{
    (void)line;
    (void)cap;
    memcpy(adu, req, (size_t)req_len);
    return req_len;
}

static int rtu_send(pymb_line *line, const uint8_t *adu, int len)
{
    return modbus_send_raw_request(line->ctx, adu, len) < 0 ? -1 : 0;
}

int pymbi_rtu_reply_length(const uint8_t *adu, int have, int expect)
{
    if (have < 2) {
        return PYMB_FRAME_INCOMPLETE;
    }
    if (adu[1] & 0x80u) {
        return 5; /* address, function | 0x80, code, CRC */
    }
    if (expect > 0) {
        return expect + 3;
    }
    return pymb_rtu_response_length(adu, (size_t)have);
}

/* When the first byte of a reply to `req_len` bytes sent at `sent_us` can
 * arrive at the earliest: the request's own wire time (with its CRC) plus
 * t3.5, both at line->char_ns per character, less 5 % for clock tolerance;
 * 0 when line->char_ns is 0 (no such check). */
static uint64_t earliest_reply(const pymb_line *line, uint64_t sent_us, int req_len)
{
    uint64_t ns;

    if (line->char_ns == 0) {
        return 0;
    }
    ns = ((uint64_t)(req_len + 2) * 10u + 35u) * line->char_ns / 10u; /* + 3.5 chars */
    return sent_us + ns * 95u / 100u / 1000u;
}

/* A whole, CRC-correct frame from the address whose request failed while
 * its quiet window runs: its late reply, to be dropped. */
static int late_frame(pymb_line *line, int slave, const uint8_t *f, int len)
{
    return line->owed && f[0] == line->owed_slave && f[0] != slave &&
           pymb_rtu_crc_ok(f, (size_t)len);
}

/* Receive one RTU reply: whatever is there is read at once (usually one poll
 * and one read, where libmodbus makes three of each). The frame ends where
 * the transport's reply_length says, or else at line->silence_us of silence.
 * Bytes after the frame that arrived in the same read are stray: they are
 * dropped. A frame of known length must arrive within the response timeout;
 * one that ends by silence too, and its silence must have come by the
 * timeout plus that silence (so a peer that trickles bytes cannot hold a call
 * past it). With a byte timeout set, a gap longer than it after the first
 * byte of a frame of known length fails. Returns the frame's length or -1
 * and errno; *got is the number of bytes in rsp.
 *
 * The clock is read where a decision needs it: once before the first wait
 * (its start and the deadline's), after each wait, and after a read only
 * when a frame goes on (when its bytes arrived) or when the earliest reply
 * is checked: a reply whole in its first read takes two readings, not four. */
static int receive_frame(pymb_line *line, int slave, int expect, uint64_t earliest,
                         uint8_t *rsp, int cap, int *got)
{
    int fd = modbus_get_socket(line->ctx), want = -1, by_silence = 0;
    uint64_t now = pymbi_now_us();
    uint64_t deadline = now + pymbi_timeout_us(line->ctx, 0);
    uint64_t byte_us = pymbi_timeout_us(line->ctx, 1), last = 0, stale_last = 0;
    uint64_t silence = line->silence_us;

    *got = 0;
    if (cap > PYMB_RTU_MAX_ADU) {
        cap = PYMB_RTU_MAX_ADU;
    }
    while (want < 0 || (*got) < want) {
        uint64_t wait, at = 0; /* at: when this read's bytes came, if the clock was read */
        ssize_t k;
        int rc;

        if (by_silence && (*got) > 0) {
            if (now - last >= silence) {
                if (!late_frame(line, slave, rsp, *got)) {
                    return (*got); /* the frame ended by the line's silence */
                }
                *got = 0;
                by_silence = 0;
                continue;
            }
            if (now >= deadline + silence) {
                errno = ETIMEDOUT; /* still not silent when the timeout (and its t3.5) ran out */
                return -1;
            }
            wait = last + silence - now;
        } else {
            if (now >= deadline) {
                errno = ETIMEDOUT;
                return -1;
            }
            wait = deadline - now;
        }
        /* A byte timeout fails a frame of known length whose bytes stop; a
         * frame of unknown length is ended by a stop, so it does not apply. */
        if ((*got) > 0 && byte_us > 0 && !by_silence) {
            if (now - last >= byte_us) {
                errno = ETIMEDOUT; /* the reply stopped mid-frame */
                return -1;
            }
            if (last + byte_us - now < wait) {
                wait = last + byte_us - now;
            }
        }
        rc = pymbi_wait_readable(line, fd, wait);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            now = pymbi_now_us();
            continue; /* the clocks above decide (a signal is not a timeout) */
        }
        if ((*got) >= cap) {
            errno = EMBBADDATA; /* a frame of unknown length goes on past the limit */
            return -1;
        }
        k = pymbi_read(line, fd, rsp + (*got), (size_t)(cap - (*got)));
        if (k < 0) {
            if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) {
                now = pymbi_now_us();
                continue;
            }
            return -1;
        }
        if (k == 0) {
            errno = ECONNRESET; /* no more bytes will ever come (hang-up, closed) */
            return -1;
        }
        if (*got == 0 && earliest != 0) {
            at = pymbi_now_us();
            if (at < earliest || (stale_last != 0 && at - stale_last < silence)) {
                /* Bytes the device cannot have sent in answer yet (the
                 * request was still on the wire, or its t3.5 not over), or
                 * the rest of such a frame: a duplicated or late reply.
                 * Dropped. */
                stale_last = now = last = at;
                continue;
            }
        }
        (*got) += (int)k;
        /* The bytes in hand, again after each late frame dropped from their
         * front: the reply may have come in the same read behind it. */
        for (;;) {
            if (want < 0 && !by_silence) {
                want = line->tr->reply_length(rsp, *got, expect);
                if (want == PYMB_FRAME_BAD_FUNCTION) {
                    want = -1;
                    by_silence = 1;
                } else if (want == PYMB_FRAME_TOO_LONG) {
                    errno = EMBBADDATA;
                    return -1;
                } else if (want < 0) {
                    want = -1; /* more bytes are needed to tell */
                }
            }
            if (!by_silence && (*got) >= cap && (want < 0 || (*got) < want)) {
                errno = EMBBADDATA; /* longer than any RTU frame */
                return -1;
            }
            if (want > 0 && *got >= want && late_frame(line, slave, rsp, want)) {
                memmove(rsp, rsp + want, (size_t)(*got - want));
                *got -= want;
                want = -1;
                continue;
            }
            break;
        }
        if (want < 0 || (*got) < want) { /* the frame goes on: its clocks run from now */
            now = last = at != 0 ? at : pymbi_now_us();
        }
    }
    return want;
}

int pymbi_rtu_receive(pymb_line *line, const uint8_t *req, int req_len, int expect,
                      uint64_t sent_us, uint8_t *rsp, int cap, pymb_failure *fail)
{
    int got = 0;
    int n = receive_frame(line, req[0], expect, earliest_reply(line, sent_us, req_len), rsp, cap,
                          &got);

    line->rx_extra = 0;
    if (n < 0) {
        if (errno == EMBBADDATA) {
            pymbi_note_reply(fail, rsp, 3, PYMB_FRAME_TOO_LONG);
        } else if (errno == ETIMEDOUT && got > 0) {
            int saved = errno;
            if (got >= 4 && pymb_rtu_crc_ok(rsp, (size_t)got)) {
                /* A whole frame, shorter than the caller or its own byte
                 * count said. */
                pymbi_note_reply(fail, rsp, got, PYMB_FRAME_BAD_LENGTH);
                saved = EMBBADDATA;
            } else {
                pymbi_note_reply(fail, rsp, got, PYMB_FRAME_INCOMPLETE);
            }
            errno = saved;
        }
        pymbi_owe(line, req[0]);
        return -1;
    }
    line->rx_extra = got - n;
    return n;
}

int pymbi_rtu_check(pymb_line *line, const uint8_t *req, int req_len, const uint8_t *rsp, int n,
                    int expect, int *exc)
{
    int status = pymb_rtu_check_response(req, (size_t)req_len, rsp, (size_t)n, exc);

    if (status == PYMB_FRAME_BAD_CRC && expect > 0 &&
        (line->rx_extra > 0 || pymbi_input_pending(line))) {
        status = PYMB_FRAME_BAD_LENGTH; /* the frame goes on past the length the caller said */
    } else if (status == PYMB_FRAME_BAD_CRC && line->rx_extra > 0 &&
               pymb_rtu_crc_ok(rsp, (size_t)n + (size_t)line->rx_extra)) {
        /* The bytes read after it (rsp holds them) end a frame whose CRC is
         * right: the frame goes on past the length its byte count said. */
        status = PYMB_FRAME_BAD_LENGTH;
    }
    return status;
}

/* What follows a bad RTU frame cannot be told from an answer. */
int pymbi_rtu_lost_step(pymb_line *line)
{
    (void)line;
    return 1;
}

const pymb_transport pymbi_transport_rtu = {
    PYMB_FRAMING_RTU,
    1, /* modbus_new_rtu's context */
    1,
    2,
    1,
    1,
    pymbi_rtu_prepare,
    rtu_build,
    rtu_send,
    pymbi_serial_flush,
    pymbi_rtu_reply_length,
    pymbi_rtu_receive,
    pymbi_rtu_check,
    pymbi_rtu_lost_step,
    pymbi_modbus_connect,
    pymbi_modbus_close,
};
