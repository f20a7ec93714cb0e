/* SPDX-License-Identifier: MIT */
/*
 * pymb_modbus.c - pymb's request path over libmodbus (see pymb_modbus.h).
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <poll.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "pymb_internal.h"

/* pymb.h numbers errors as libmodbus does, so that the core needs no libmodbus
 * (a compile-time check: the array size is -1 when they differ; C99 has no
 * static_assert, and libmodbus's exception codes are enum constants, which #if
 * cannot see). */
typedef char pymb_emb_codes_match_libmodbus
    [(PYMB_ENOBASE == MODBUS_ENOBASE && PYMB_EMBXILFUN == EMBXILFUN &&
      PYMB_EMBXGTAR == EMBXGTAR && PYMB_EMBBADCRC == EMBBADCRC &&
      PYMB_EMBBADDATA == EMBBADDATA && PYMB_EMBBADEXC == EMBBADEXC &&
      PYMB_EMBUNKEXC == EMBUNKEXC && PYMB_EMBMDATA == EMBMDATA &&
      PYMB_EMBBADSLAVE == EMBBADSLAVE) ? 1 : -1];

#define MBAP_LENGTH 7

static uint64_t now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

int pymb_exception_errno(int code)
{
    if (code < 1 || code > 255) {
        return EMBBADEXC;
    }
    return code <= 0x0B ? MODBUS_ENOBASE + code : PYMB_EXCEPTION_ENOBASE + code;
}

int pymb_errno_exception(int errnum)
{
    if (errnum >= EMBXILFUN && errnum <= EMBXGTAR) {
        return errnum - MODBUS_ENOBASE;
    }
    if (errnum >= PYMB_EXCEPTION_ENOBASE + 0x0C && errnum <= PYMB_EXCEPTION_ENOBASE + 0xFF) {
        return errnum - PYMB_EXCEPTION_ENOBASE;
    }
    return 0;
}

uint32_t pymb_rtu_silence_us(int baud)
{
    if (baud < 1) {
        errno = EINVAL;
        return 0;
    }
    if (baud > 19200) {
        return PYMB_T35_FLOOR_US;
    }
    /* 3.5 characters of 11 bits: 38.5 bit times, rounded up. */
    return (uint32_t)((38500000u + (uint32_t)baud * 1u - 1u) / (uint32_t)baud);
}

uint32_t pymb_rtu_char_ns(int baud, int bits)
{
    if (baud < 1 || bits < 7 || bits > 12) {
        errno = EINVAL;
        return 0;
    }
    return (uint32_t)(((uint64_t)bits * 1000000000u + (uint64_t)baud - 1u) / (uint64_t)baud);
}

int pymb_line_init(pymb_line *line, modbus_t *ctx, int framing, uint32_t silence_us)
{
    int hl;

    if (line == NULL || ctx == NULL) {
        errno = EINVAL;
        return -1;
    }
    hl = modbus_get_header_length(ctx);
    if (!((framing == PYMB_FRAMING_RTU && hl == 1) ||
          ((framing == PYMB_FRAMING_TCP || framing == PYMB_FRAMING_RTU_OVER_TCP) &&
           hl == MBAP_LENGTH))) {
        errno = EINVAL;
        return -1;
    }
    memset(line, 0, sizeof *line);
    line->ctx = ctx;
    line->framing = framing;
    line->silence_us = silence_us ? silence_us : PYMB_T35_FLOOR_US;
    return 0;
}

static int line_ok(const pymb_line *line)
{
    return line != NULL && line->ctx != NULL && modbus_get_socket(line->ctx) >= 0;
}

/* Wait up to wait_us for fd to be readable: 1 readable, 0 not yet (the wait
 * ended or a signal came and the hook let it pass: the caller's own clock
 * decides), -1 and errno on error or when the hook asks to stop (EINTR).
 * poll, not select: any descriptor number works (select stops at FD_SETSIZE).
 * With a hook, no single poll lasts longer than PYMB_INTERRUPT_SLICE_US. */
static int wait_readable(pymb_line *line, int fd, uint64_t wait_us)
{
    struct pollfd p;
    uint64_t slice = wait_us;
    int rc;

    if (line->interrupted != NULL && slice > PYMB_INTERRUPT_SLICE_US) {
        slice = PYMB_INTERRUPT_SLICE_US;
    }
    p.fd = fd;
    p.events = POLLIN;
    p.revents = 0;
    rc = poll(&p, 1, (int)((slice + 999u) / 1000u));
    if (rc > 0) {
        return 1;
    }
    if (rc < 0 && errno != EINTR) {
        return -1;
    }
    if (line->interrupted != NULL && (rc < 0 || slice < wait_us) &&
        line->interrupted(line->interrupt_arg)) {
        errno = EINTR;
        return -1;
    }
    return 0;
}

static uint64_t timeout_us(modbus_t *ctx, int byte)
{
    uint32_t sec = 0, usec = 0;
    if (byte) {
        modbus_get_byte_timeout(ctx, &sec, &usec);
    } else {
        modbus_get_response_timeout(ctx, &sec, &usec);
    }
    return (uint64_t)sec * 1000000u + usec;
}

/* Read and drop input until the line has been silent for quiet_us since
 * `last` (or since the last byte seen), or until max_us from now. */
static int drain_since(pymb_line *line, uint64_t last, uint64_t quiet_us, uint64_t max_us)
{
    uint8_t junk[MODBUS_MAX_ADU_LENGTH];
    uint64_t start = now_us();
    int fd = modbus_get_socket(line->ctx), dropped = 0;

    for (;;) {
        uint64_t now = now_us(), quiet_end = last + quiet_us, hard_end = start + max_us;
        ssize_t n;
        int rc;

        /* Pending input is read first whatever the clock says: its bytes may
         * have arrived at any time since `last`, so they restart the window. */
        rc = (now >= quiet_end || now >= hard_end)
                 ? wait_readable(line, fd, 0)
                 : wait_readable(line, fd, (quiet_end < hard_end ? quiet_end : hard_end) - now);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            if (now_us() >= quiet_end || now_us() >= hard_end) {
                break;
            }
            continue;
        }
        n = read(fd, junk, sizeof junk);
        if (n > 0) {
            dropped += (int)n;
            last = now_us();
            if (last >= hard_end) {
                break;
            }
        } else if (n == 0) {
            break; /* TCP peer closed or pty hung up: nothing more can arrive */
        } else if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
            return -1;
        }
    }
    pymb_flush(line);
    return dropped;
}

/* Whether input is waiting to be read now (no waiting). */
static int input_pending(const pymb_line *line)
{
    struct pollfd p;

    p.fd = modbus_get_socket(line->ctx);
    p.events = POLLIN;
    p.revents = 0;
    return poll(&p, 1, 0) > 0;
}

int pymb_flush(pymb_line *line)
{
    struct pollfd p;

    if (!line_ok(line)) {
        errno = EINVAL;
        return -1;
    }
    /* A zero-timeout poll first: flushing an empty line is a system call
     * (tcflush) per request for nothing. */
    p.fd = modbus_get_socket(line->ctx);
    p.events = POLLIN;
    p.revents = 0;
    if (poll(&p, 1, 0) == 0) {
        return 0;
    }
    return modbus_flush(line->ctx) < 0 ? -1 : 0;
}

int pymb_drain(pymb_line *line, uint32_t quiet_us, uint32_t max_us)
{
    if (!line_ok(line)) {
        errno = EINVAL;
        return -1;
    }
    return drain_since(line, now_us(), quiet_us, max_us);
}

static uint64_t quiet_window_us(pymb_line *line)
{
    uint64_t quiet = timeout_us(line->ctx, 0);
    return quiet > 60000000u ? 60000000u : quiet;
}

/* Before a request to `slave`: pay what remains of a quiet window owed after
 * a failure (silence for the response timeout, at most 60 s, counted from
 * the failure; at most four windows long), or, on a line without one,
 * discard pending input (RTU) or keep it (TCP: complete replies to earlier
 * transactions are dropped by their id as they are read). */
static int before_request(pymb_line *line, int slave)
{
    uint64_t quiet;

    if (!line->owed) {
        return line->framing == PYMB_FRAMING_TCP ? 0 : pymb_flush(line);
    }
    quiet = quiet_window_us(line);
    if (line->framing != PYMB_FRAMING_TCP && slave != line->owed_slave) {
        /* Another address: no wait (see the header); rtu_receive drops the
         * failed address's frames while the window runs. */
        if (now_us() >= line->owed_since_us + quiet) {
            line->owed = 0;
        }
        return pymb_flush(line);
    }
    if (drain_since(line, line->owed_since_us, quiet, 4 * quiet) < 0) {
        return -1;
    }
    line->owed = 0;
    return 0;
}

static void owe(pymb_line *line, int slave)
{
    line->owed = 1;
    line->owed_slave = slave;
    line->owed_since_us = now_us();
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

/* Receive one RTU reply (serial line or RTU over TCP): whatever is there is
 * read at once (usually one poll and one read, where libmodbus makes three
 * of each). The frame ends where its function code and byte count say
 * (pymb_rtu_response_length), or at `expect_total` bytes when the caller
 * knows the length, or else at line->silence_us of silence. Bytes after the
 * frame that arrived in the same read are stray: they are dropped. A frame
 * of known length must arrive within the response timeout; one that ends by
 * silence too, and its silence must have come by the timeout plus that
 * silence (so a peer that trickles bytes cannot hold a call past it). With a
 * byte timeout set, a gap longer than it after the first byte of a frame of
 * known length fails. Returns the frame's length or -1 and errno; *got is
 * the number of bytes in rsp. */
static int rtu_receive(pymb_line *line, int slave, int expect_total, uint64_t earliest,
                       uint8_t *rsp, int cap, int *got)
{
    int fd = modbus_get_socket(line->ctx), want = -1, by_silence = 0;
    uint64_t deadline = now_us() + timeout_us(line->ctx, 0);
    uint64_t byte_us = timeout_us(line->ctx, 1), last = 0, stale_last = 0;
    uint64_t silence = line->silence_us;

    *got = 0;
    if (cap > PYMB_RTU_MAX_ADU) {
        cap = PYMB_RTU_MAX_ADU;
    }
    while (want < 0 || (*got) < want) {
        uint64_t now = now_us(), wait;
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
        rc = wait_readable(line, fd, wait);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            continue; /* the clocks above decide (a signal is not a timeout) */
        }
        if ((*got) >= cap) {
            errno = EMBBADDATA; /* a frame of unknown length goes on past the limit */
            return -1;
        }
        k = read(fd, rsp + (*got), (size_t)(cap - (*got)));
        if (k < 0) {
            if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) {
                continue;
            }
            return -1;
        }
        if (k == 0) {
            errno = ECONNRESET; /* no more bytes will ever come (hang-up, closed) */
            return -1;
        }
        last = now_us();
        if (*got == 0 && earliest != 0 &&
            (last < earliest || (stale_last != 0 && last - stale_last < silence))) {
            /* Bytes the device cannot have sent in answer yet (the request
             * was still on the wire, or its t3.5 not over), or the rest of
             * such a frame: a duplicated or late reply. Dropped. */
            stale_last = last;
            continue;
        }
        (*got) += (int)k;
        if (want < 0 && !by_silence && (*got) >= 2) {
            if (rsp[1] & 0x80u) {
                want = 5; /* address, function | 0x80, code, CRC */
            } else if (expect_total > 0) {
                want = expect_total;
            } else {
                want = pymb_rtu_response_length(rsp, (size_t)(*got));
                if (want == PYMB_FRAME_BAD_FUNCTION) {
                    want = -1;
                    by_silence = 1;
                } else if (want == PYMB_FRAME_TOO_LONG) {
                    errno = EMBBADDATA;
                    return -1;
                }
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
        }
    }
    return want;
}

/* Read exactly n bytes into buf before `deadline`. Returns n, or -1 and
 * errno; *got says how many arrived (a partial frame desynchronises). */
static int read_exact(pymb_line *line, int fd, uint8_t *buf, int n, uint64_t deadline, int *got)
{
    *got = 0;
    while (*got < n) {
        uint64_t now = now_us();
        ssize_t k;
        int rc;

        if (now >= deadline) {
            errno = ETIMEDOUT;
            return -1;
        }
        rc = wait_readable(line, fd, deadline - now);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            continue;
        }
        k = read(fd, buf + *got, (size_t)(n - *got));
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

/* Receive the Modbus TCP reply to transaction line->tid: frames for other
 * transactions are read and dropped, and the wait goes on until the
 * deadline. Returns the ADU length (MBAP + PDU), or -1 and errno; *status
 * is PYMB_FRAME_BAD_HEADER for a protocol id or length that cannot be, and
 * *desync 1 when the stream may be out of step (a partial frame read). */
static int tcp_receive(pymb_line *line, uint8_t *rsp, int *status, int *desync)
{
    int fd = modbus_get_socket(line->ctx), got = 0;
    uint64_t deadline = now_us() + timeout_us(line->ctx, 0);

    for (;;) {
        unsigned tid, proto, length;

        if (read_exact(line, fd, rsp, MBAP_LENGTH, deadline, &got) < 0) {
            *desync = got > 0;
            return -1;
        }
        tid = (unsigned)rsp[0] << 8 | rsp[1];
        proto = (unsigned)rsp[2] << 8 | rsp[3];
        length = (unsigned)rsp[4] << 8 | rsp[5];
        /* [MB-TCP] 3.1.3: length counts the unit id and the PDU (1..253). */
        if (proto != 0 || length < 2 || length > 1 + PYMB_MAX_PDU) {
            *status = PYMB_FRAME_BAD_HEADER;
            *desync = 1;
            errno = EMBBADDATA;
            return -1;
        }
        if (read_exact(line, fd, rsp + MBAP_LENGTH, (int)length - 1, deadline, &got) < 0) {
            *desync = 1;
            return -1;
        }
        if (tid == line->tid) {
            return 6 + (int)length;
        }
        /* A reply to an earlier (timed-out) transaction: drop it, wait on. */
    }
}

static int send_all(pymb_line *line, int fd, const uint8_t *b, size_t n)
{
    while (n > 0) {
        ssize_t k = send(fd, b, n, MSG_NOSIGNAL);
        if (k < 0) {
            if (errno == EINTR) {
                continue;
            }
            if (errno == EAGAIN || errno == EWOULDBLOCK) {
                struct pollfd p = {fd, POLLOUT, 0};
                if (poll(&p, 1, (int)(timeout_us(line->ctx, 0) / 1000u) + 1) == 0) {
                    errno = ETIMEDOUT;
                    return -1;
                }
                continue;
            }
            return -1;
        }
        b += k;
        n -= (size_t)k;
    }
    return 0;
}

/* Frame and send the request as the line's framing wants it. */
static int send_request(pymb_line *line, const uint8_t *req, int req_len)
{
    uint8_t adu[MBAP_LENGTH + PYMB_MAX_PDU + 2];
    int fd = modbus_get_socket(line->ctx);

    switch (line->framing) {
    case PYMB_FRAMING_TCP:
        line->tid = (uint16_t)(line->tid + 1u);
        adu[0] = (uint8_t)(line->tid >> 8);
        adu[1] = (uint8_t)line->tid;
        adu[2] = 0;
        adu[3] = 0;
        adu[4] = (uint8_t)(req_len >> 8);
        adu[5] = (uint8_t)req_len;
        memcpy(adu + 6, req, (size_t)req_len);
        return send_all(line, fd, adu, (size_t)req_len + 6);
    case PYMB_FRAMING_RTU_OVER_TCP:
        memcpy(adu, req, (size_t)req_len);
        pymb_rtu_append_crc(adu, (size_t)req_len, sizeof adu);
        return send_all(line, fd, adu, (size_t)req_len + 2);
    default: /* RTU: libmodbus appends the CRC and drives RTS */
        return modbus_send_raw_request(line->ctx, req, req_len) < 0 ? -1 : 0;
    }
}

static void note_request(pymb_failure *fail, const uint8_t *req, int req_len, int header)
{
    if (fail == NULL) {
        return;
    }
    fail->function = req_len > 1 ? req[1] : -1;
    fail->address = req_len > 3 ? (req[2] << 8 | req[3]) : -1;
    fail->count = req_len > 5 ? (req[4] << 8 | req[5]) : -1;
    fail->frame = 0;
    fail->rsp_len = 0;
    fail->header = header;
}

static void note_reply(pymb_failure *fail, const uint8_t *rsp, int len, int frame)
{
    if (fail == NULL) {
        return;
    }
    if (len < 0) {
        len = 0;
    }
    if (len > (int)sizeof fail->rsp) {
        len = (int)sizeof fail->rsp;
    }
    memcpy(fail->rsp, rsp, (size_t)len);
    fail->rsp_len = len;
    fail->frame = frame;
}

static int frame_errno(int status)
{
    switch (status) {
    case PYMB_FRAME_BAD_CRC:
        return EMBBADCRC;
    case PYMB_FRAME_BAD_SLAVE:
        return EMBBADSLAVE;
    default:
        return EMBBADDATA;
    }
}

/* [MB-SL] 2.1: no reply to a broadcast, but the devices need the frame to
 * end (a silence) and time to act before the next request ("turnaround
 * delay", 100 to 200 ms there): wait until it is sent, then
 * PYMB_BROADCAST_TURNAROUND_US. */
static void broadcast_wait(pymb_line *line)
{
    struct timespec ts = {PYMB_BROADCAST_TURNAROUND_US / 1000000,
                          (PYMB_BROADCAST_TURNAROUND_US % 1000000) * 1000L};
    if (line->framing == PYMB_FRAMING_RTU) {
        tcdrain(modbus_get_socket(line->ctx));
    }
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

/* Receive the RTU reply to req and check it against req: its length (-1 and
 * errno on failure, the line then owing a quiet window), *status and *exc. */
static int rtu_reply(pymb_line *line, const uint8_t *req, int req_len, int expect,
                     uint64_t sent_us, uint8_t *rsp, int rsp_cap, pymb_failure *fail,
                     int *status, int *exc)
{
    int got = 0;
    int n = rtu_receive(line, req[0], expect > 0 ? expect + 3 : 0,
                        earliest_reply(line, sent_us, req_len), rsp, rsp_cap, &got);
    if (n < 0) {
        if (errno == EMBBADDATA) {
            note_reply(fail, rsp, 3, PYMB_FRAME_TOO_LONG);
        } else if (errno == ETIMEDOUT && got > 0) {
            int saved = errno;
            if (expect > 0 && got >= 4 && pymb_rtu_crc_ok(rsp, (size_t)got)) {
                /* A whole frame, shorter than the caller said. */
                note_reply(fail, rsp, got, PYMB_FRAME_BAD_LENGTH);
                saved = EMBBADDATA;
            } else {
                note_reply(fail, rsp, got, PYMB_FRAME_INCOMPLETE);
            }
            errno = saved;
        }
        owe(line, req[0]);
        return -1;
    }
    *status = pymb_rtu_check_response(req, (size_t)req_len, rsp, (size_t)n, exc);
    if (*status == PYMB_FRAME_BAD_CRC && expect > 0 && (got > n || input_pending(line))) {
        *status = PYMB_FRAME_BAD_LENGTH; /* the frame goes on past the length the caller said */
    }
    return n;
}

/* The same for a Modbus TCP reply: its MBAP header, unit id and PDU. */
static int tcp_reply(pymb_line *line, const uint8_t *req, int req_len, uint8_t *rsp,
                     pymb_failure *fail, int *status, int *exc)
{
    int desync = 0;
    int n = tcp_receive(line, rsp, status, &desync);
    if (n < 0) {
        if (*status != PYMB_FRAME_OK) {
            note_reply(fail, rsp, MBAP_LENGTH, *status);
        }
        if (desync) {
            owe(line, req[0]);
        }
        return -1;
    }
    if (rsp[MBAP_LENGTH - 1] != req[0]) {
        *status = PYMB_FRAME_BAD_SLAVE;
    } else {
        *status = pymb_check_response_pdu(req + 1, (size_t)req_len - 1, rsp + MBAP_LENGTH,
                                          (size_t)(n - MBAP_LENGTH), exc);
    }
    return n;
}

int pymb_transact(pymb_line *line, const uint8_t *req, int req_len, int expect,
                  uint8_t *rsp, int rsp_cap, pymb_failure *fail)
{
    int hl, n, status = PYMB_FRAME_OK, pdu_len, exc = 0;
    uint64_t sent_us;

    pymb_failure_reset(fail);
    if (!line_ok(line) || req == NULL || rsp == NULL || req_len < 2 ||
        req_len > PYMB_MAX_PDU + 1 || rsp_cap < MODBUS_MAX_ADU_LENGTH || expect < 0 ||
        expect > PYMB_MAX_PDU) {
        errno = EINVAL;
        return -1;
    }
    hl = line->framing == PYMB_FRAMING_TCP ? MBAP_LENGTH : 1;
    note_request(fail, req, req_len, hl);
    if (before_request(line, req[0]) < 0) {
        return -1;
    }
    sent_us = now_us();
    if (send_request(line, req, req_len) < 0) {
        owe(line, req[0]);
        return -1;
    }
    if (hl == 1 && req[0] == MODBUS_BROADCAST_ADDRESS) {
        broadcast_wait(line);
        return 0;
    }
    if (hl == 1) {
        n = rtu_reply(line, req, req_len, expect, sent_us, rsp, rsp_cap, fail, &status, &exc);
        pdu_len = n - 3;
    } else {
        n = tcp_reply(line, req, req_len, rsp, fail, &status, &exc);
        pdu_len = n - MBAP_LENGTH;
    }
    if (n < 0) {
        return -1;
    }
    if (status == PYMB_FRAME_OK && expect > 0 && pdu_len != expect) {
        status = PYMB_FRAME_BAD_LENGTH;
    }
    if (status == PYMB_FRAME_OK) {
        return pdu_len;
    }
    note_reply(fail, rsp, n, status);
    if (status == PYMB_FRAME_EXCEPTION) {
        /* A well-formed answer: the line is in step, nothing to recover. */
        errno = pymb_exception_errno(exc);
        return -1;
    }
    /* RTU: what follows a bad frame cannot be told from an answer: owe a
     * quiet window. TCP: the MBAP length delimited the frame, so the stream
     * is in step (later frames are sorted by transaction id) unless bytes
     * are already waiting behind it (a length that lied): only then. */
    if (hl == 1 || input_pending(line)) {
        owe(line, req[0]);
    }
    errno = frame_errno(status);
    return -1;
}

static int check_read_args(pymb_line *line, int slave, int addr, int nb, const void *dest)
{
    /* A read needs a reply: no RTU broadcast. TCP unit identifiers are 0..255. */
    int lowest = (line != NULL && line->framing != PYMB_FRAMING_TCP) ? 1 : 0;

    if (line == NULL || dest == NULL || slave < lowest || slave > 255 || addr < 0 ||
        addr > 65535 || nb < 1 || nb > 65536 - addr) {
        errno = EINVAL;
        return -1;
    }
    return 0;
}

/* One read request (function, slave, address, count): the checked reply's
 * data, after the byte count, or NULL and errno. */
static const uint8_t *read_request(pymb_line *line, int function, int slave, int a, int n,
                                   uint8_t *rsp, pymb_failure *fail)
{
    uint8_t req[6];

    req[0] = (uint8_t)slave;
    req[1] = (uint8_t)function;
    req[2] = (uint8_t)(a >> 8);
    req[3] = (uint8_t)a;
    req[4] = (uint8_t)(n >> 8);
    req[5] = (uint8_t)n;
    if (pymb_transact(line, req, 6, 0, rsp, MODBUS_MAX_ADU_LENGTH, fail) < 0) {
        return NULL;
    }
    /* pymb_transact checked the function code and the byte count. */
    return rsp + (line->framing == PYMB_FRAMING_TCP ? MBAP_LENGTH : 1) + 2;
}

int pymb_read_registers(pymb_line *line, int function, int slave, int addr, int nb,
                        uint16_t *dest, pymb_failure *fail)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    int done = 0;

    pymb_failure_reset(fail);
    if ((function != MODBUS_FC_READ_HOLDING_REGISTERS &&
         function != MODBUS_FC_READ_INPUT_REGISTERS) ||
        check_read_args(line, slave, addr, nb, dest) < 0) {
        errno = EINVAL;
        return -1;
    }
    while (done < nb) {
        int n = nb - done > MODBUS_MAX_READ_REGISTERS ? MODBUS_MAX_READ_REGISTERS : nb - done;
        const uint8_t *data = read_request(line, function, slave, addr + done, n, rsp, fail);
        int i;

        if (data == NULL) {
            return -1;
        }
        for (i = 0; i < n; i++) {
            dest[done + i] = (uint16_t)(data[2 * i] << 8 | data[2 * i + 1]);
        }
        done += n;
    }
    return nb;
}

int pymb_read_bits(pymb_line *line, int function, int slave, int addr, int nb, uint8_t *dest,
                   pymb_failure *fail)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    int done = 0;

    pymb_failure_reset(fail);
    if ((function != MODBUS_FC_READ_COILS && function != MODBUS_FC_READ_DISCRETE_INPUTS) ||
        check_read_args(line, slave, addr, nb, dest) < 0) {
        errno = EINVAL;
        return -1;
    }
    while (done < nb) {
        int n = nb - done > MODBUS_MAX_READ_BITS ? MODBUS_MAX_READ_BITS : nb - done;
        const uint8_t *data = read_request(line, function, slave, addr + done, n, rsp, fail);
        int i;

        if (data == NULL) {
            return -1;
        }
        for (i = 0; i < n; i++) { /* ceil(n / 8) bytes, least significant bit first */
            dest[done + i] = (uint8_t)((data[i / 8] >> (i % 8)) & 1u);
        }
        done += n;
    }
    return nb;
}
