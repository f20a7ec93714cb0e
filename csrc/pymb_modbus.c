/*
 * pymb_modbus.c - pymb's request path over libmodbus (see pymb_modbus.h).
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <poll.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "pymb_modbus.h"

static uint64_t now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

int pymb_flush(modbus_t *ctx)
{
    struct pollfd p;

    if (ctx == NULL) {
        errno = EINVAL;
        return -1;
    }
    /* A zero-timeout poll first: flushing an empty line is a system call
     * (tcflush) per request for nothing. */
    p.fd = modbus_get_socket(ctx);
    p.events = POLLIN;
    p.revents = 0;
    if (p.fd >= 0 && poll(&p, 1, 0) == 0) {
        return 0;
    }
    return modbus_flush(ctx) < 0 ? -1 : 0;
}

/* Wait up to wait_us for fd to be readable: 1 readable, 0 not yet (timeout
 * or EINTR: the caller's own deadline decides), -1 and errno on error.
 * poll, not select: any descriptor number works (select stops at FD_SETSIZE). */
static int wait_readable(int fd, uint64_t wait_us)
{
    struct pollfd p;
    int rc;

    p.fd = fd;
    p.events = POLLIN;
    p.revents = 0;
    rc = poll(&p, 1, (int)((wait_us + 999u) / 1000u));
    if (rc < 0 && errno == EINTR) {
        return 0;
    }
    return rc < 0 ? -1 : (rc > 0);
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

/* Receive one RTU reply: whatever is there is read at once (usually one poll
 * and one read, where libmodbus makes three of each), and the frame ends
 * where its function code and byte count say (pymb_rtu_response_length, the
 * rule libmodbus reads by too). Bytes after the frame that arrived in the
 * same read are stray: they are dropped. The whole reply must arrive within
 * the response timeout; with a byte timeout set, a gap longer than it after
 * the first byte also fails. Returns the frame's length or -1 and errno. */
static int rtu_receive(modbus_t *ctx, uint8_t *rsp, int cap)
{
    int fd = modbus_get_socket(ctx), got = 0, want = -1;
    uint64_t deadline = now_us() + timeout_us(ctx, 0);
    uint64_t byte_us = timeout_us(ctx, 1);

    while (want < 0 || got < want) {
        uint64_t now = now_us(), wait;
        ssize_t k;
        int rc;

        if (now >= deadline) {
            errno = ETIMEDOUT;
            return -1;
        }
        wait = deadline - now;
        if (got > 0 && byte_us > 0 && byte_us < wait) {
            wait = byte_us;
        }
        rc = wait_readable(fd, wait);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            if (got > 0 && byte_us > 0 && now_us() < deadline) {
                errno = ETIMEDOUT; /* the reply stopped mid-frame */
                return -1;
            }
            continue; /* the deadline check above decides */
        }
        k = read(fd, rsp + got, (size_t)(cap - got));
        if (k < 0) {
            if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) {
                continue;
            }
            return -1;
        }
        if (k == 0) {
            errno = ECONNRESET; /* no more bytes will ever come (pty hung up) */
            return -1;
        }
        got += (int)k;
        if (want < 0) {
            want = pymb_rtu_response_length(rsp, (size_t)got);
            if (want == PYMB_FRAME_TOO_LONG || want > cap) {
                errno = EMBBADDATA;
                return -1;
            }
        }
        if (got >= cap && (want < 0 || got < want)) {
            errno = EMBBADDATA;
            return -1;
        }
    }
    return want;
}

int pymb_drain(modbus_t *ctx, uint32_t quiet_us, uint32_t max_us)
{
    uint8_t junk[MODBUS_MAX_ADU_LENGTH];
    uint64_t start, last, now;
    int fd, dropped = 0;

    if (ctx == NULL || (fd = modbus_get_socket(ctx)) < 0) {
        errno = EINVAL;
        return -1;
    }
    start = last = now_us();
    for (;;) {
        uint64_t wait, quiet_end = last + quiet_us, hard_end = start + max_us;
        ssize_t n;
        int rc;

        now = now_us();
        if (now >= quiet_end || now >= hard_end) {
            break;
        }
        wait = (quiet_end < hard_end ? quiet_end : hard_end) - now;
        rc = wait_readable(fd, wait);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            continue; /* the quiet window (checked above) may have ended */
        }
        n = read(fd, junk, sizeof junk);
        if (n > 0) {
            dropped += (int)n;
            last = now_us();
        } else if (n == 0) {
            break; /* TCP peer closed or pty hung up: nothing more can arrive */
        } else if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
            return -1;
        }
    }
    pymb_flush(ctx);
    return dropped;
}

void pymb_recover(modbus_t *ctx)
{
    int saved = errno;
    uint32_t sec = 0, usec = 0;
    uint64_t quiet;

    if (ctx != NULL && modbus_get_response_timeout(ctx, &sec, &usec) == 0) {
        quiet = (uint64_t)sec * 1000000u + usec;
        if (quiet > 60000000u) {
            quiet = 60000000u;
        }
        pymb_drain(ctx, (uint32_t)quiet, (uint32_t)(4 * quiet));
    }
    errno = saved;
}

static void note_request(pymb_failure *fail, const uint8_t *req, int req_len)
{
    if (fail == NULL) {
        return;
    }
    fail->function = req_len > 1 ? req[1] : -1;
    fail->address = req_len > 3 ? (req[2] << 8 | req[3]) : -1;
    fail->count = req_len > 5 ? (req[4] << 8 | req[5]) : -1;
    fail->frame = 0;
    fail->rsp_len = 0;
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

int pymb_transact(modbus_t *ctx, const uint8_t *req, int req_len, uint8_t *rsp,
                  int rsp_cap, pymb_failure *fail)
{
    int hl, n, len, status, pdu_len, exc = 0;

    if (ctx == NULL || req == NULL || rsp == NULL || req_len < 2 ||
        req_len > MODBUS_MAX_PDU_LENGTH + 1 || rsp_cap < MODBUS_MAX_ADU_LENGTH) {
        errno = EINVAL;
        return -1;
    }
    hl = modbus_get_header_length(ctx);
    if (hl < 1) {
        errno = EINVAL;
        return -1;
    }
    note_request(fail, req, req_len);
    if (pymb_flush(ctx) < 0 || modbus_send_raw_request(ctx, req, req_len) < 0) {
        pymb_recover(ctx);
        return -1;
    }
    if (hl == 1 && req[0] == MODBUS_BROADCAST_ADDRESS) {
        /* [MB-SL] 2.1: no reply to a broadcast, but the devices need the
         * frame to end (a silence) and time to act before the next request
         * ("turnaround delay", 100 to 200 ms there): wait until it is sent,
         * then PYMB_BROADCAST_TURNAROUND_US. */
        struct timespec ts = {PYMB_BROADCAST_TURNAROUND_US / 1000000,
                              (PYMB_BROADCAST_TURNAROUND_US % 1000000) * 1000L};
        tcdrain(modbus_get_socket(ctx));
        while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
        }
        return 0;
    }
    /* RTU: pymb's own receive (one read where libmodbus makes three); TCP:
     * libmodbus's, which parses the MBAP header. Either way the checks below
     * are all pymb's. */
    n = hl == 1 ? rtu_receive(ctx, rsp, rsp_cap) : modbus_receive_confirmation(ctx, rsp);
    if (n < 0) {
        if (errno == EMBBADDATA) {
            note_reply(fail, rsp, 3, PYMB_FRAME_TOO_LONG);
        }
        pymb_recover(ctx);
        return -1;
    }
    if (hl == 1) {
        len = n;
        status = pymb_rtu_check_response(req, (size_t)req_len, rsp, (size_t)len, &exc);
        pdu_len = len - 3;
    } else {
        len = n;
        if (len < hl + 1 || len > rsp_cap) {
            status = PYMB_FRAME_BAD_LENGTH;
        } else if (rsp[hl - 1] != req[0]) {
            status = PYMB_FRAME_BAD_SLAVE;
        } else {
            status = pymb_check_response_pdu(req + 1, (size_t)req_len - 1, rsp + hl,
                                             (size_t)(len - hl), &exc);
        }
        pdu_len = len - hl;
    }
    if (status == PYMB_FRAME_OK) {
        return pdu_len;
    }
    note_reply(fail, rsp, len, status);
    if (status == PYMB_FRAME_EXCEPTION) {
        /* A well-formed answer: the line is in step, nothing to recover. */
        errno = (exc >= 1 && exc < MODBUS_EXCEPTION_MAX) ? MODBUS_ENOBASE + exc : EMBBADEXC;
        return -1;
    }
    errno = frame_errno(status);
    pymb_recover(ctx);
    return -1;
}

static int check_read_args(modbus_t *ctx, int slave, int addr, int nb, const void *dest)
{
    /* A read needs a reply: no RTU broadcast. TCP unit identifiers are 0..255. */
    int lowest = (ctx != NULL && modbus_get_header_length(ctx) == 1) ? 1 : 0;

    if (ctx == NULL || dest == NULL || slave < lowest || slave > 255 || addr < 0 ||
        addr > 65535 || nb < 1 || nb > 65536 - addr) {
        errno = EINVAL;
        return -1;
    }
    return 0;
}

/* One read request (function, slave, address, count): the checked reply's
 * data, after the byte count, or NULL and errno. */
static const uint8_t *read_request(modbus_t *ctx, int function, int slave, int a, int n,
                                   uint8_t *rsp, pymb_failure *fail)
{
    uint8_t req[6];

    req[0] = (uint8_t)slave;
    req[1] = (uint8_t)function;
    req[2] = (uint8_t)(a >> 8);
    req[3] = (uint8_t)a;
    req[4] = (uint8_t)(n >> 8);
    req[5] = (uint8_t)n;
    if (pymb_transact(ctx, req, 6, rsp, MODBUS_MAX_ADU_LENGTH, fail) < 0) {
        return NULL;
    }
    /* pymb_transact checked the function code and the byte count. */
    return rsp + modbus_get_header_length(ctx) + 2;
}

int pymb_read_registers(modbus_t *ctx, int function, int slave, int addr, int nb,
                        uint16_t *dest, pymb_failure *fail)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    int done = 0;

    if ((function != MODBUS_FC_READ_HOLDING_REGISTERS &&
         function != MODBUS_FC_READ_INPUT_REGISTERS) ||
        check_read_args(ctx, slave, addr, nb, dest) < 0) {
        errno = EINVAL;
        return -1;
    }
    while (done < nb) {
        int n = nb - done > MODBUS_MAX_READ_REGISTERS ? MODBUS_MAX_READ_REGISTERS : nb - done;
        const uint8_t *data = read_request(ctx, function, slave, addr + done, n, rsp, fail);
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

int pymb_read_bits(modbus_t *ctx, int function, int slave, int addr, int nb, uint8_t *dest,
                   pymb_failure *fail)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    int done = 0;

    if ((function != MODBUS_FC_READ_COILS && function != MODBUS_FC_READ_DISCRETE_INPUTS) ||
        check_read_args(ctx, slave, addr, nb, dest) < 0) {
        errno = EINVAL;
        return -1;
    }
    while (done < nb) {
        int n = nb - done > MODBUS_MAX_READ_BITS ? MODBUS_MAX_READ_BITS : nb - done;
        const uint8_t *data = read_request(ctx, function, slave, addr + done, n, rsp, fail);
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
