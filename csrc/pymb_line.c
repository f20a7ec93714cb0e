/* SPDX-License-Identifier: MIT */
/*
 * pymb_line.c - a line's life (pymb_line_new/free and its settings), the
 * errno of a Modbus exception, the wire-time helpers, and the waits and
 * quiet window every transport shares (see pymb_modbus.h).
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <poll.h>
#include <stdlib.h>
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

/* The transports pymb_line_new can choose from, one file each. */
static const pymb_transport *const transports[] = {
    &pymbi_transport_rtu,
    &pymbi_transport_tcp,
    &pymbi_transport_rtu_over_tcp,
    &pymbi_transport_ascii,
    &pymbi_transport_udp,
};

pymb_line *pymb_line_new(modbus_t *ctx, pymb_framing framing, uint32_t silence_us)
{
    const pymb_transport *tr = NULL;
    pymb_line *line;
    size_t i;

    for (i = 0; i < sizeof transports / sizeof transports[0]; i++) {
        if (transports[i]->framing == framing) {
            tr = transports[i];
        }
    }
    if (ctx == NULL || tr == NULL || modbus_get_header_length(ctx) != tr->ctx_header_length) {
        errno = EINVAL;
        return NULL;
    }
    line = calloc(1, sizeof *line);
    if (line == NULL) {
        errno = ENOMEM;
        return NULL;
    }
    line->ctx = ctx;
    line->tr = tr;
    line->silence_us = silence_us ? silence_us : PYMB_T35_FLOOR_US;
    return line;
}

void pymb_line_free(pymb_line *line)
{
    free(line);
}

int pymb_line_set_interrupt(pymb_line *line, int (*interrupted)(void *arg), void *arg)
{
    if (line == NULL) {
        errno = EINVAL;
        return -1;
    }
    line->interrupted = interrupted;
    line->interrupt_arg = arg;
    return 0;
}

int pymb_line_set_io(pymb_line *line, const pymb_line_io *io)
{
    if (line == NULL ||
        (io != NULL && (io->read == NULL || io->write == NULL || io->pending == NULL))) {
        errno = EINVAL;
        return -1;
    }
    if (io == NULL) {
        memset(&line->io, 0, sizeof line->io);
    } else {
        line->io = *io;
    }
    return 0;
}

/* Read up to n bytes from the line: the I/O's read (pymb_line_set_io) or
 * the descriptor's. The count, 0 at the end of the stream, -1 and errno. */
ssize_t pymbi_read(pymb_line *line, int fd, uint8_t *buf, size_t n)
{
    int rc;

    if (line->io.read == NULL) {
        return read(fd, buf, n);
    }
    rc = line->io.read(line->io.arg, buf, n > 65536u ? 65536 : (int)n);
    if (rc < 0) {
        errno = -rc;
        return -1;
    }
    return rc > (int)n ? (ssize_t)n : rc;
}

int pymb_line_set_char_ns(pymb_line *line, uint32_t char_ns)
{
    if (line == NULL) {
        errno = EINVAL;
        return -1;
    }
    line->char_ns = char_ns;
    return 0;
}

int pymb_line_connect(pymb_line *line, const char *node, const char *service)
{
    if (line == NULL) {
        errno = EINVAL;
        return -1;
    }
    if (modbus_get_socket(line->ctx) >= 0) {
        return 0; /* open already */
    }
    line->owed = 0;
    return line->tr->connect(line, node, service);
}

void pymb_line_close(pymb_line *line)
{
    if (line != NULL && modbus_get_socket(line->ctx) >= 0) {
        line->tr->close(line);
    }
}

int pymb_line_set_retries(pymb_line *line, int retries)
{
    if (line == NULL || retries < 0 || retries > PYMB_MAX_RETRIES) {
        errno = EINVAL;
        return -1;
    }
    line->retries = retries;
    return 0;
}

int pymbi_modbus_connect(pymb_line *line, const char *node, const char *service)
{
    (void)node;
    (void)service;
    if (modbus_connect(line->ctx) == -1) {
        /* libmodbus 3.1.6 waits for a TCP connect for the response timeout
         * and leaves connect()'s EINPROGRESS in errno when it passes */
        if (errno == EINPROGRESS) {
            errno = ETIMEDOUT;
        }
        return -1;
    }
    return 0;
}

void pymbi_modbus_close(pymb_line *line)
{
    modbus_close(line->ctx);
}

uint16_t pymbi_line_tid(const pymb_line *line)
{
    return line == NULL ? 0 : (uint16_t)(line->tid + 1u);
}

void pymbi_line_set_tid(pymb_line *line, uint16_t tid)
{
    if (line != NULL) {
        line->tid = (uint16_t)(tid - 1u);
    }
}

int pymb_line_header_length(const pymb_line *line)
{
    if (line == NULL) {
        errno = EINVAL;
        return -1;
    }
    return line->tr->header_length;
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

uint64_t pymbi_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

int pymbi_line_ok(const pymb_line *line)
{
    return line != NULL && line->ctx != NULL && modbus_get_socket(line->ctx) >= 0;
}

/* Wait up to wait_us for fd to be readable: 1 readable, 0 not yet (the wait
 * ended or a signal came and the hook let it pass: the caller's own clock
 * decides), -1 and errno on error or when the hook asks to stop (EINTR).
 * poll, not select: any descriptor number works (select stops at FD_SETSIZE).
 * With a hook, no single poll lasts longer than PYMB_INTERRUPT_SLICE_US. */
int pymbi_wait_readable(pymb_line *line, int fd, uint64_t wait_us)
{
    struct pollfd p;
    uint64_t slice = wait_us;
    int rc;

    if (line->io.pending != NULL && line->io.pending(line->io.arg) > 0) {
        return 1; /* already decrypted: no wait */
    }
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

uint64_t pymbi_timeout_us(modbus_t *ctx, int byte)
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
int pymbi_drain_since(pymb_line *line, uint64_t last, uint64_t quiet_us, uint64_t max_us)
{
    uint8_t junk[MODBUS_MAX_ADU_LENGTH];
    uint64_t start = pymbi_now_us();
    int fd = modbus_get_socket(line->ctx), dropped = 0;

    for (;;) {
        uint64_t now = pymbi_now_us(), quiet_end = last + quiet_us, hard_end = start + max_us;
        ssize_t n;
        int rc;

        /* Pending input is read first whatever the clock says: its bytes may
         * have arrived at any time since `last`, so they restart the window. */
        rc = (now >= quiet_end || now >= hard_end)
                 ? pymbi_wait_readable(line, fd, 0)
                 : pymbi_wait_readable(line, fd,
                                       (quiet_end < hard_end ? quiet_end : hard_end) - now);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            if (pymbi_now_us() >= quiet_end || pymbi_now_us() >= hard_end) {
                break;
            }
            continue;
        }
        n = pymbi_read(line, fd, junk, sizeof junk);
        if (n > 0) {
            dropped += (int)n;
            last = pymbi_now_us();
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
int pymbi_input_pending(const pymb_line *line)
{
    struct pollfd p;

    if (line->io.pending != NULL && line->io.pending(line->io.arg) > 0) {
        return 1;
    }
    p.fd = modbus_get_socket(line->ctx);
    p.events = POLLIN;
    p.revents = 0;
    return poll(&p, 1, 0) > 0;
}

int pymb_flush(pymb_line *line)
{
    if (!pymbi_line_ok(line)) {
        errno = EINVAL;
        return -1;
    }
    /* A zero-timeout poll first: flushing an empty line is a system call
     * (tcflush) per request for nothing. */
    if (!pymbi_input_pending(line)) {
        return 0;
    }
    if (line->io.read != NULL) {
        /* Not modbus_flush: it would read the descriptor under the I/O. What
         * is there now is dropped (a bounded number of reads). */
        uint8_t junk[MODBUS_MAX_ADU_LENGTH];
        int i;

        for (i = 0; i < 64 && pymbi_input_pending(line); i++) {
            ssize_t n = pymbi_read(line, modbus_get_socket(line->ctx), junk, sizeof junk);
            if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
                return n < 0 ? -1 : 0;
            }
        }
        return 0;
    }
    return modbus_flush(line->ctx) < 0 ? -1 : 0;
}

int pymb_drain(pymb_line *line, uint32_t quiet_us, uint32_t max_us)
{
    if (!pymbi_line_ok(line)) {
        errno = EINVAL;
        return -1;
    }
    return pymbi_drain_since(line, pymbi_now_us(), quiet_us, max_us);
}

uint64_t pymbi_quiet_window_us(pymb_line *line)
{
    uint64_t quiet = pymbi_timeout_us(line->ctx, 0);
    return quiet > 60000000u ? 60000000u : quiet;
}

/* Pay what remains of an owed quiet window: silence for the response
 * timeout (at most 60 s) counted from the failure, at most four windows. */
int pymbi_pay_owed(pymb_line *line)
{
    uint64_t quiet = pymbi_quiet_window_us(line);

    if (pymbi_drain_since(line, line->owed_since_us, quiet, 4 * quiet) < 0) {
        return -1;
    }
    line->owed = 0;
    return 0;
}

void pymbi_owe(pymb_line *line, int slave)
{
    line->owed = 1;
    line->owed_slave = slave;
    line->owed_since_us = pymbi_now_us();
}

/* Every byte of b to the line's descriptor, by send(2) on a socket or
 * write(2) on a serial line (where send fails with ENOTSOCK), waiting for
 * room at most the response timeout. */
static int put_all(pymb_line *line, int sock, const uint8_t *b, size_t n)
{
    int fd = modbus_get_socket(line->ctx);

    while (n > 0) {
        ssize_t k = sock ? send(fd, b, n, MSG_NOSIGNAL) : write(fd, b, n);
        if (k < 0) {
            if (errno == EINTR) {
                continue;
            }
            if (errno == EAGAIN || errno == EWOULDBLOCK) {
                struct pollfd p = {fd, POLLOUT, 0};
                if (poll(&p, 1, (int)(pymbi_timeout_us(line->ctx, 0) / 1000u) + 1) == 0) {
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

int pymbi_send_all(pymb_line *line, const uint8_t *b, size_t n)
{
    if (line->io.write != NULL) {
        int rc = n > 65536u ? -EMSGSIZE : line->io.write(line->io.arg, b, (int)n);
        if (rc < 0) {
            errno = -rc;
            return -1;
        }
        return 0;
    }
    return put_all(line, 1, b, n);
}

int pymbi_write_all(pymb_line *line, const uint8_t *b, size_t n)
{
    return put_all(line, 0, b, n);
}

void pymbi_no_flush(pymb_line *line)
{
    (void)line;
}

void pymbi_serial_flush(pymb_line *line)
{
    tcdrain(modbus_get_socket(line->ctx));
}

void pymbi_note_reply(pymb_failure *fail, const uint8_t *rsp, int len, int frame)
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
