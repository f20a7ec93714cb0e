/* SPDX-License-Identifier: MIT */
/*
 * test_request.c - known-answer tests of the request path (pymb_transact,
 * pymb_read_registers, pymb_read_bits, pymb_read_plan, and the extension's
 * held plans, pymbi_plan_run) on every transport,
 * against a scripted responder: a child process playing the device on the
 * other end of a real pseudo-terminal (RTU, through libmodbus's serial code) or of a
 * socket pair (Modbus TCP, RTU over TCP).
 *
 * The responder is independent of the code under test: it frames with its
 * own bit-by-bit CRC ([MB-SL] 6.2.2) and MBAP header ([MB-TCP] 3.1.3), and
 * every request pymb sends is compared byte for byte with the frame the
 * specification gives for it. Each script waits on the bytes it receives,
 * never on the clock, except where the clock is the subject (late replies,
 * the byte timeout); every wait is bounded.
 */
#define _XOPEN_SOURCE 700
#define _DEFAULT_SOURCE

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "../pymb_internal.h"
#include "check.h"
#include "crc_ref.h"

/* The test's own clock (its CRC is crc_ref.h's), apart from the library's. */
static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static void sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

/* ------------------------------------------------------------------------ */
/* The device end.                                                          */

enum kind { RTU, TCP, RTU_TCP, ASCII, UDP };

/* An MBAP header frames the kind's requests and replies (TCP, UDP). */
static int mbap(enum kind k)
{
    return k == TCP || k == UDP;
}

/* [MB-SL] 2.5.2.2, the test's own: the two's complement of the bytes' sum. */
static uint8_t lrc_ref(const uint8_t *b, size_t n)
{
    unsigned sum = 0;
    while (n-- > 0) {
        sum = (sum + *b++) & 0xFFu;
    }
    return (uint8_t)((0x100u - sum) & 0xFFu);
}

/* b[0..n) as an ASCII frame: ':', two upper-case hexadecimal digits a byte,
 * CR LF. */
static size_t ascii_text(const uint8_t *b, size_t n, uint8_t *out)
{
    size_t i, k = 0;
    out[k++] = ':';
    for (i = 0; i < n; i++) {
        k += (size_t)sprintf((char *)out + k, "%02X", b[i]);
    }
    out[k++] = '\r';
    out[k++] = '\n';
    return k;
}

/* An ASCII request's text back to bytes (address, PDU, LRC): their count,
 * 0 when it is not one whole frame. */
static int ascii_bytes(const uint8_t *t, int n, uint8_t *out)
{
    int i, k = 0;
    if (n < 5 || t[0] != ':' || t[n - 2] != '\r' || t[n - 1] != '\n' || (n - 3) % 2 != 0) {
        return 0;
    }
    for (i = 1; i + 1 < n - 2; i += 2) {
        unsigned v;
        char two[3] = {(char)t[i], (char)t[i + 1], 0};
        if (sscanf(two, "%2X", &v) != 1) {
            return 0;
        }
        out[k++] = (uint8_t)v;
    }
    return k;
}

struct dev;
/* Called for each request received (the ADU as it came, CRC or MBAP
 * included); answers with dev_reply/dev_send. */
typedef void (*handler)(struct dev *d, const uint8_t *req, int n);

/* In memory shared with the child that runs the script (a process, not a
 * thread: qemu-user 7.2 hangs in pthread_create, and a process is closer to
 * a device anyway). */
struct dev {
    enum kind kind;
    int fd;                 /* the device's end */
    handler handle;
    volatile int stop;
    volatile int requests;  /* requests received so far */
    uint8_t last[300];      /* the last request, as received */
    volatile int last_len;
    int state;              /* the script's own counter */
    volatile int param;     /* the script's parameter, set by the test */
    pid_t master;           /* the test's process, for the signal scripts */
    volatile int ready;     /* the device runs: the timeouts count from here */
};

static void dev_send(struct dev *d, const uint8_t *b, size_t n)
{
    while (n > 0) {
        ssize_t k = write(d->fd, b, n);
        if (k < 0) {
            if (errno == EAGAIN || errno == EINTR) {
                struct pollfd p = {d->fd, POLLOUT, 0};
                poll(&p, 1, 100);
                continue;
            }
            return;
        }
        b += k;
        n -= (size_t)k;
    }
}

/* Frame `pdu` (function code first) from `unit` as the device's transport
 * wants it into out: RTU with the CRC, TCP with an MBAP header carrying `tid`. */
static size_t frame(enum kind kind, unsigned tid, int unit, const uint8_t *pdu, size_t n,
                    uint8_t *out)
{
    size_t h = 0;
    if (kind == ASCII) {
        uint8_t b[300];
        b[0] = (uint8_t)unit;
        memcpy(b + 1, pdu, n);
        b[n + 1] = lrc_ref(b, n + 1);
        return ascii_text(b, n + 2, out);
    }
    if (mbap(kind)) {
        out[0] = (uint8_t)(tid >> 8);
        out[1] = (uint8_t)tid;
        out[2] = 0;
        out[3] = 0;
        out[4] = (uint8_t)((n + 1) >> 8);
        out[5] = (uint8_t)(n + 1);
        h = 6;
    }
    out[h] = (uint8_t)unit;
    memcpy(out + h + 1, pdu, n);
    if (mbap(kind)) {
        return h + 1 + n;
    }
    {
        uint16_t crc = crc_bitwise(out, n + 1);
        out[n + 1] = (uint8_t)crc;
        out[n + 2] = (uint8_t)(crc >> 8);
    }
    return n + 3;
}

/* The request's transaction id (TCP), unit and PDU. */
static unsigned req_tid(const struct dev *d, const uint8_t *req)
{
    return mbap(d->kind) ? ((unsigned)req[0] << 8 | req[1]) : 0;
}
static int req_unit(const struct dev *d, const uint8_t *req)
{
    return req[mbap(d->kind) ? 6 : 0];
}
static const uint8_t *req_pdu(const struct dev *d, const uint8_t *req)
{
    return req + (mbap(d->kind) ? 7 : 1);
}

/* Answer the request with pdu from its own unit. */
static void dev_reply(struct dev *d, const uint8_t *req, const uint8_t *pdu, size_t n)
{
    uint8_t out[600]; /* ASCII: two characters a byte */
    size_t len = frame(d->kind, req_tid(d, req), req_unit(d, req), pdu, n, out);
    dev_send(d, out, len);
}

/* A read's reply: register i holds base + address + i. */
static void dev_read_reply(struct dev *d, const uint8_t *req, unsigned base)
{
    const uint8_t *p = req_pdu(d, req);
    unsigned addr = (unsigned)p[1] << 8 | p[2], count = (unsigned)p[3] << 8 | p[4], i;
    uint8_t pdu[256];

    pdu[0] = p[0];
    pdu[1] = (uint8_t)(2 * count);
    for (i = 0; i < count && i < 125; i++) {
        unsigned v = (base + addr + i) & 0xFFFFu;
        pdu[2 + 2 * i] = (uint8_t)(v >> 8);
        pdu[3 + 2 * i] = (uint8_t)v;
    }
    dev_reply(d, req, pdu, 2 + 2 * count);
}

static void dev_exception(struct dev *d, const uint8_t *req, int code)
{
    uint8_t pdu[2];
    pdu[0] = (uint8_t)(req_pdu(d, req)[0] | 0x80u);
    pdu[1] = (uint8_t)code;
    dev_reply(d, req, pdu, 2);
}

/* Receive one request: the bytes that come until 5 ms of quiet (pymb sends
 * each request in one write). 0 when none came within 50 ms. */
static int dev_receive(struct dev *d, uint8_t *buf, int cap)
{
    struct pollfd p = {d->fd, POLLIN, 0};
    int n = 0;

    if (poll(&p, 1, 50) <= 0) {
        return 0;
    }
    while (n < cap) {
        ssize_t k = read(d->fd, buf + n, (size_t)(cap - n));
        if (k <= 0) {
            if (k < 0 && (errno == EAGAIN || errno == EINTR)) {
                if (poll(&p, 1, 5) <= 0) {
                    break;
                }
                continue;
            }
            break;
        }
        n += (int)k;
        if (d->kind == UDP || poll(&p, 1, 5) <= 0) { /* UDP: one datagram */
            break;
        }
    }
    return n;
}

static void dev_run(struct dev *d)
{
    uint8_t req[300];

    d->ready = 1;
    while (!d->stop) {
        int n = dev_receive(d, req, (int)sizeof req);
        if (n <= 0) {
            continue;
        }
        memcpy(d->last, req, (size_t)n);
        d->last_len = n;
        d->requests++;
        if (d->kind == ASCII) {
            /* The scripts take bytes: the text as the device decodes it. */
            n = ascii_bytes(d->last, n, req);
            if (n == 0) {
                continue;
            }
        }
        if (d->handle != NULL) {
            d->handle(d, req, n);
        }
    }
}

/* ------------------------------------------------------------------------ */
/* The master end: a libmodbus context and a pymb line on each transport.   */

struct rig {
    enum kind kind;
    modbus_t *ctx;
    pymb_line *line;
    struct dev *dev;        /* shared with the device's process */
    pid_t child;
};

static int rig_open(struct rig *r, enum kind kind)
{
    memset(r, 0, sizeof *r);
    r->kind = kind;
    r->dev = mmap(NULL, sizeof *r->dev, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1,
                  0);
    if (r->dev == MAP_FAILED) {
        perror("mmap");
        return -1;
    }
    memset(r->dev, 0, sizeof *r->dev);
    r->dev->kind = kind;
    if (kind == RTU || kind == ASCII) {
        struct termios tio;
        int m = posix_openpt(O_RDWR | O_NOCTTY);
        if (m < 0 || grantpt(m) != 0 || unlockpt(m) != 0) {
            perror("pty");
            return -1;
        }
        tcgetattr(m, &tio);
        cfmakeraw(&tio);
        tcsetattr(m, TCSANOW, &tio);
        fcntl(m, F_SETFL, fcntl(m, F_GETFL) | O_NONBLOCK);
        r->dev->fd = m;
        r->ctx = modbus_new_rtu(ptsname(m), 115200, 'N', 8, 1);
        if (r->ctx == NULL || modbus_connect(r->ctx) == -1) {
            perror("modbus_new_rtu");
            return -1;
        }
    } else {
        int sp[2];
        if (socketpair(AF_UNIX, kind == UDP ? SOCK_DGRAM : SOCK_STREAM, 0, sp) != 0) {
            perror("socketpair");
            return -1;
        }
        fcntl(sp[1], F_SETFL, fcntl(sp[1], F_GETFL) | O_NONBLOCK);
        r->dev->fd = sp[1];
        r->ctx = modbus_new_tcp("127.0.0.1", 502);
        if (r->ctx == NULL || modbus_set_socket(r->ctx, sp[0]) == -1) {
            perror("modbus_new_tcp");
            return -1;
        }
    }
    modbus_set_response_timeout(r->ctx, 0, 300000);
    modbus_set_byte_timeout(r->ctx, 0, 0);
    {
        static const pymb_framing framings[] = {PYMB_FRAMING_RTU, PYMB_FRAMING_TCP,
                                                PYMB_FRAMING_RTU_OVER_TCP, PYMB_FRAMING_ASCII,
                                                PYMB_FRAMING_UDP};
        r->line = pymb_line_new(r->ctx, framings[kind], 2000);
    }
    if (r->line == NULL) {
        perror("pymb_line_new");
        return -1;
    }
    return 0;
}

static void rig_start(struct rig *r, handler h)
{
    r->dev->handle = h;
    r->dev->stop = 0;
    r->dev->requests = 0;
    r->dev->state = 0;
    r->dev->master = getpid();
    r->dev->ready = 0;
    fflush(NULL);
    r->child = fork();
    if (r->child < 0) {
        perror("fork");
        exit(2);
    }
    if (r->child == 0) {
        dev_run(r->dev);
        _exit(0);
    }
    /* A loaded machine (the sanitizers' fork) can take longer than a
     * response timeout (300 ms) to start the child: wait for it (10 s). */
    for (int i = 0; !r->dev->ready && i < 10000; i++) {
        usleep(1000);
    }
}

static void rig_stop(struct rig *r)
{
    int status;
    r->dev->stop = 1;
    while (waitpid(r->child, &status, 0) < 0 && errno == EINTR) {
    }
}

static void rig_close(struct rig *r)
{
    pymb_line_free(r->line);
    modbus_close(r->ctx);
    modbus_free(r->ctx);
    close(r->dev->fd);
    munmap(r->dev, sizeof *r->dev);
}

/* The request as the specification frames it: compared with what came. */
static int last_request_is(const struct rig *r, unsigned tid, int unit, const uint8_t *pdu,
                           size_t n)
{
    uint8_t want[300];
    size_t len = frame(r->kind, tid, unit, pdu, n, want);
    return r->dev->last_len == (int)len && memcmp(r->dev->last, want, len) == 0;
}

static const char *kind_name(enum kind k)
{
    static const char *const names[] = {"RTU", "TCP", "RTU over TCP", "ASCII", "UDP"};
    return names[k];
}

/* ------------------------------------------------------------------------ */
/* Scripts.                                                                 */

static void answer_reads(struct dev *d, const uint8_t *req, int n)
{
    (void)n;
    dev_read_reply(d, req, 1000);
}

static void answer_bits(struct dev *d, const uint8_t *req, int n)
{
    /* [MB-AP] 6.1's example: coils 20..38 read as CD 6B 05. */
    const uint8_t pdu[] = {0x01, 0x03, 0xCD, 0x6B, 0x05};
    (void)n;
    dev_reply(d, req, pdu, sizeof pdu);
}

static void answer_echo(struct dev *d, const uint8_t *req, int n)
{
    uint8_t pdu[5];
    (void)n;
    memcpy(pdu, req_pdu(d, req), 5);
    if (d->state++ == 1) {
        pdu[4] ^= 1; /* the second answer's echo differs from the write */
    }
    dev_reply(d, req, pdu, 5);
}

/* Exception d->param. */
static void answer_exception(struct dev *d, const uint8_t *req, int n)
{
    (void)n;
    dev_exception(d, req, d->param);
}

/* The reply in three pieces, 20 ms apart (well inside the timeouts). */
static void answer_split(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t pdu[] = {0x03, 0x06, 0x00, 0x01, 0x00, 0x02, 0x00, 0x03};
    uint8_t out[300];
    size_t len = frame(d->kind, req_tid(d, req), req_unit(d, req), pdu, sizeof pdu, out);
    (void)n;
    dev_send(d, out, 2);
    sleep_ms(20);
    dev_send(d, out + 2, 5);
    sleep_ms(20);
    dev_send(d, out + 7, len - 7);
}

/* The first request answered only after the response timeout (300 ms): a
 * late reply, with other values than the answers that follow. */
static void answer_late_first(struct dev *d, const uint8_t *req, int n)
{
    (void)n;
    if (d->state++ == 0) {
        sleep_ms(450);
        dev_read_reply(d, req, 5000);
    } else {
        dev_read_reply(d, req, 1000);
    }
}

/* Silent to the first request; the second is answered by the first's late
 * reply and its own answer in one write: one read holds both. */
static void answer_late_and_reply_together(struct dev *d, const uint8_t *req, int n)
{
    uint8_t both[64], late[300];
    const uint8_t pdu[] = {0x03, 0x04, 0x13, 0x88, 0x13, 0x89}; /* 5000, 5001 */
    size_t k;
    (void)n;
    if (d->state++ == 0) {
        return;
    }
    k = frame(d->kind, 0, 5, pdu, sizeof pdu, late);
    memcpy(both, late, k);
    {
        const uint8_t mine[] = {0x03, 0x04, 0x03, 0xE8, 0x03, 0xE9}; /* 1000, 1001 */
        k += frame(d->kind, 0, req_unit(d, req), mine, sizeof mine, both + k);
    }
    dev_send(d, both, k);
}

static void answer_bad_crc(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t pdu[] = {0x03, 0x02, 0x12, 0x34};
    uint8_t out[300];
    size_t len = frame(d->kind, req_tid(d, req), req_unit(d, req), pdu, sizeof pdu, out);
    (void)n;
    if (d->kind == ASCII) {
        out[len - 3] = out[len - 3] == '0' ? '1' : '0'; /* the LRC's last digit */
    } else {
        out[len - 1] ^= 0xFF;
    }
    dev_send(d, out, len);
}

static void answer_other_unit(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t pdu[] = {0x03, 0x02, 0x12, 0x34};
    uint8_t out[300];
    size_t len = frame(d->kind, req_tid(d, req), req_unit(d, req) + 1, pdu, sizeof pdu, out);
    (void)n;
    dev_send(d, out, len);
}

/* TCP: first a reply to an older transaction (other values), then the answer. */
static void answer_old_tid_first(struct dev *d, const uint8_t *req, int n)
{
    uint8_t old[300];
    memcpy(old, req, (size_t)n);
    old[1] = (uint8_t)(old[1] - 1u);
    if (old[1] == 0xFF) {
        old[0] = (uint8_t)(old[0] - 1u);
    }
    dev_read_reply(d, old, 5000);
    dev_read_reply(d, req, 1000);
}

static void answer_bad_protocol(struct dev *d, const uint8_t *req, int n)
{
    uint8_t out[300];
    const uint8_t pdu[] = {0x03, 0x02, 0x12, 0x34};
    size_t len = frame(d->kind, req_tid(d, req), req_unit(d, req), pdu, sizeof pdu, out);
    (void)n;
    out[3] = 1; /* protocol id 1 */
    dev_send(d, out, len);
}

/* A function code whose reply length only the line's silence tells. */
static void answer_user_function(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t pdu[] = {0x41, 0xAA, 0xBB, 0xCC};
    (void)n;
    dev_reply(d, req, pdu, sizeof pdu);
}

/* The hub ([HUB] 3): registers 31..630 answer address + 0; a request that
 * touches 631..730 (the firmware lacks the second temperature block)
 * answers exception 02, as firmware before V2.23 does. The first request
 * is answered busy (exception 04, [HUB] 2.3.2.3) d->param times. */
static void answer_hub(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t *p = req_pdu(d, req);
    unsigned addr = (unsigned)p[1] << 8 | p[2], count = (unsigned)p[3] << 8 | p[4];
    (void)n;
    if (d->state < d->param) {
        d->state++;
        dev_exception(d, req, 0x04);
    } else if (addr + count - 1 >= 631) {
        dev_exception(d, req, 0x02);
    } else {
        dev_read_reply(d, req, 0);
    }
}

/* Silent, but sends the main thread SIGUSR1 60 ms after the request. */
static void answer_signal_silence(struct dev *d, const uint8_t *req, int n)
{
    (void)req;
    (void)n;
    sleep_ms(60);
    kill(d->master, SIGUSR1);
}

/* A signal 30 ms after the request, then the answer 30 ms later. */
static void answer_signal_then_reply(struct dev *d, const uint8_t *req, int n)
{
    (void)n;
    sleep_ms(30);
    kill(d->master, SIGUSR1);
    sleep_ms(30);
    dev_read_reply(d, req, 1000);
}

static volatile sig_atomic_t got_signal;
static void on_signal(int sig)
{
    (void)sig;
    got_signal = 1;
}
static int stop_on_signal(void *arg)
{
    int *calls = arg;
    (*calls)++;
    return got_signal != 0;
}
static int never_stop(void *arg)
{
    int *calls = arg;
    (*calls)++;
    return 0;
}

/* ------------------------------------------------------------------------ */
/* Tests.                                                                   */

static void test_reads(enum kind k)
{
    struct rig r;
    uint16_t regs[130];
    uint8_t bits[19];
    pymb_failure fail;
    int unit = mbap(k) ? 0 : 250; /* 250: above libmodbus's 247 */

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    rig_start(&r, answer_reads);
    /* [MB-AP] 6.3: 03, address 31, 3 registers. */
    {
        const uint8_t pdu[] = {0x03, 0x00, 0x1F, 0x00, 0x03};
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, unit, 31, 3, regs,
                                  &fail) == 3);
        CHECK(last_request_is(&r, 1, unit, pdu, sizeof pdu));
        CHECK(regs[0] == 1031 && regs[1] == 1032 && regs[2] == 1033);
    }
    /* 130 registers: two requests, 125 then 5 ([MB-AP] 6.4's limit). */
    {
        const uint8_t pdu[] = {0x04, 0x00, 0x7D, 0x00, 0x05};
        r.dev->requests = 0;
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_INPUT_REGISTERS, unit, 0, 130, regs,
                                  &fail) == 130);
        CHECK(r.dev->requests == 2);
        CHECK(last_request_is(&r, 3, unit, pdu, sizeof pdu));
        {
            int k2, all = 1;
            for (k2 = 0; k2 < 130; k2++) {
                all &= regs[k2] == 1000 + k2; /* every register, in 4s and one by one */
            }
            CHECK(all);
        }
    }
    rig_stop(&r);
    /* [MB-AP] 6.1: read coils 20..38 (19 bits) answered CD 6B 05. */
    rig_start(&r, answer_bits);
    {
        const uint8_t pdu[] = {0x01, 0x00, 0x13, 0x00, 0x13};
        const uint8_t want[19] = {1, 0, 1, 1, 0, 0, 1, 1, 1, 1, 0, 1, 0, 1, 1, 0, 1, 0, 1};
        CHECK(pymb_read_bits(r.line, MODBUS_FC_READ_COILS, unit, 19, 19, bits, &fail) == 19);
        CHECK(last_request_is(&r, 4, unit, pdu, sizeof pdu));
        CHECK(memcmp(bits, want, sizeof want) == 0);
    }
    rig_stop(&r);
    /* A write's echo: equal passes, different fails with BAD_ECHO. */
    rig_start(&r, answer_echo);
    {
        const uint8_t req[] = {(uint8_t)unit, 0x06, 0x00, 0x01, 0x00, 0x03};
        uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
        int h = pymb_line_header_length(r.line);
        CHECK(h == (mbap(k) ? 7 : 1));
        CHECK(pymb_transact(r.line, req, sizeof req, 0, rsp, sizeof rsp, &fail) == 5);
        CHECK(memcmp(rsp + h, req + 1, 5) == 0);
        errno = 0;
        CHECK(pymb_transact(r.line, req, sizeof req, 0, rsp, sizeof rsp, &fail) == -1 &&
              errno == EMBBADDATA && fail.frame == PYMB_FRAME_BAD_ECHO);
        CHECK(fail.function == 0x06 && fail.address == 1 && fail.count == 3);
        CHECK(fail.rsp_len == (mbap(k) ? 12 : k == ASCII ? 7 : 8) && fail.header == h);
    }
    rig_stop(&r);
    rig_close(&r);
    printf("%s: reads, bits, echo\n", kind_name(k));
}

static void test_exceptions(enum kind k)
{
    struct rig r;
    uint16_t regs[2];
    pymb_failure fail;
    int code, ok = 1;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    rig_start(&r, answer_exception);
    /* Every request is answered at once: no check below is about time, so a
     * long timeout keeps a loaded machine (or qemu) from failing one of the
     * 255 by a scheduling delay past the rig's 300 ms. */
    modbus_set_response_timeout(r.ctx, 3, 0);
    /* [MB-AP] 7: any code 01..FF on the wire; each its own errno. */
    for (code = 1; code <= 0xFF; code++) {
        int e;
        r.dev->param = code;
        errno = 0;
        if (pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 7, 100, 2, regs,
                                &fail) != -1) {
            ok = 0;
            continue;
        }
        e = errno;
        if (e != pymb_exception_errno(code) || pymb_errno_exception(e) != code ||
            fail.frame != PYMB_FRAME_EXCEPTION || fail.rsp_len != (mbap(k) ? 9 : k == ASCII ? 4 : 5) ||
            fail.rsp[fail.header] != 0x83 || fail.rsp[fail.header + 1] != code ||
            strcmp(pymb_strerror(e), strerror(e)) == 0) {
            fprintf(stderr, "%s: exception %02X: errno %d\n", kind_name(k), code, e);
            ok = 0;
        }
    }
    CHECK(ok);
    CHECK(r.dev->requests == 255);
    modbus_set_response_timeout(r.ctx, 0, 300000);
    /* A well-formed exception leaves the line in step: no quiet window, so
     * the next request goes out at once and is answered. */
    rig_stop(&r);
    rig_start(&r, answer_reads);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 7, 100, 2, regs,
                              &fail) == 2 && regs[1] == 1101);
    rig_stop(&r);
    rig_close(&r);
    printf("%s: exceptions 01..FF\n", kind_name(k));
}

static void test_split_and_bad(enum kind k)
{
    struct rig r;
    uint16_t regs[3];
    pymb_failure fail;
    double t0;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    /* A reply in three pieces is one reply (a datagram cannot be split). */
    rig_start(&r, answer_split);
    if (k != UDP) {
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 9, 0, 3, regs,
                                  &fail) == 3);
        CHECK(regs[0] == 1 && regs[1] == 2 && regs[2] == 3);
    }
    /* With a byte timeout shorter than the gaps, the reply stops mid-frame
     * (RTU: the byte timeout applies to a frame of known length; ASCII: it
     * is the inter-character timeout, which drops the frame begun). */
    if (!mbap(k)) {
        modbus_set_byte_timeout(r.ctx, 0, 5000);
        errno = 0;
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 9, 0, 3, regs,
                                  &fail) == -1 && errno == ETIMEDOUT);
        CHECK(fail.frame == PYMB_FRAME_INCOMPLETE && (k == ASCII || fail.rsp_len == 2));
        modbus_set_byte_timeout(r.ctx, 0, 0);
        sleep_ms(60); /* the rest of the split reply arrives and is owed away */
    }
    rig_stop(&r);

    rig_start(&r, mbap(k) ? answer_bad_protocol : answer_bad_crc);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 9, 0, 1, regs, &fail) ==
          -1);
    if (k == TCP) {
        CHECK(errno == EMBBADDATA && fail.frame == PYMB_FRAME_BAD_HEADER);
    } else if (k == UDP) {
        /* not a Modbus datagram: dropped, the wait went on; the timeout shows it */
        CHECK(errno == ETIMEDOUT && fail.frame == PYMB_FRAME_BAD_HEADER && fail.rsp_len > 0);
    } else {
        CHECK(errno == EMBBADCRC && fail.frame == PYMB_FRAME_BAD_CRC &&
              fail.rsp_len == (k == ASCII ? 6 : 7));
    }
    rig_stop(&r);

    rig_start(&r, answer_other_unit);
    errno = 0;
    if (k == UDP) {
        /* Another unit's datagram is not the answer: dropped (the timeout
         * shows it). */
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 9, 0, 1, regs,
                                  &fail) == -1 && errno == ETIMEDOUT &&
              fail.frame == PYMB_FRAME_BAD_SLAVE && fail.rsp[fail.header - 1] == 10);
    } else {
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 9, 0, 1, regs,
                                  &fail) == -1 && errno == EMBBADSLAVE &&
              fail.frame == PYMB_FRAME_BAD_SLAVE);
        CHECK(fail.rsp[fail.header - 1] == 10);
    }
    rig_stop(&r);

    /* Silence: ETIMEDOUT after the response timeout (300 ms), not before. */
    rig_start(&r, NULL);
    t0 = now_s();
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 9, 0, 1, regs, &fail) ==
          -1 && errno == ETIMEDOUT && fail.rsp_len == 0);
    CHECK(now_s() - t0 >= 0.29);
    rig_stop(&r);
    rig_close(&r);
    printf("%s: split reads, bad frames, silence\n", kind_name(k));
}

static void test_late_and_stale(enum kind k)
{
    struct rig r;
    uint16_t regs[2];
    pymb_failure fail;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    /* A late reply to a request that timed out is never the next answer:
     * the next request to that address waits for a quiet line. */
    rig_start(&r, answer_late_first);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 5, 0, 2, regs, &fail) ==
          -1 && errno == ETIMEDOUT);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 5, 0, 2, regs, &fail) ==
          2);
    CHECK(regs[0] == 1000 && regs[1] == 1001); /* not the late 5000, 5001 */
    CHECK(r.dev->requests == 2);
    rig_stop(&r);

    if (!mbap(k)) {
        /* Another address does not wait; the failed address's late frame,
         * arriving during its request, is dropped. */
        rig_start(&r, answer_late_first);
        errno = 0;
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 5, 0, 2, regs,
                                  &fail) == -1 && errno == ETIMEDOUT);
        modbus_set_response_timeout(r.ctx, 1, 0);
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 6, 0, 2, regs,
                                  &fail) == 2);
        CHECK(regs[0] == 1000 && regs[1] == 1001);
        modbus_set_response_timeout(r.ctx, 0, 300000);
        rig_stop(&r);
        sleep_ms(350); /* let the window pass */

        /* The late frame and the answer in one read: the frame is dropped
         * from the front and the answer behind it taken. */
        rig_start(&r, answer_late_and_reply_together);
        errno = 0;
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 5, 0, 2, regs,
                                  &fail) == -1 && errno == ETIMEDOUT);
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 6, 0, 2, regs,
                                  &fail) == 2);
        CHECK(regs[0] == 1000 && regs[1] == 1001);
        rig_stop(&r);
        sleep_ms(350);
    }

    /* Stale bytes waiting before the request are not its answer. */
    rig_start(&r, mbap(k) ? answer_old_tid_first : answer_reads);
    if (!mbap(k)) {
        const uint8_t pdu[] = {0x03, 0x04, 0x00, 0x07, 0x00, 0x08};
        uint8_t out[32];
        size_t len = frame(k, 0, 5, pdu, sizeof pdu, out);
        dev_send(r.dev, out, len);
        sleep_ms(20);
    }
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 5, 0, 2, regs, &fail) ==
          2);
    CHECK(regs[0] == 1000 && regs[1] == 1001);
    rig_stop(&r);
    rig_close(&r);
    printf("%s: late and stale replies\n", kind_name(k));
}

/* pymbi_plan_run (the extension's held plans): the plan as pymb_read_plan
 * runs it, then its decode, only once every request from `start` on has its
 * reply; a refused request decodes nothing, the rest run from the one after
 * does. Against answer_hub: 31..40 and 40..41 read, 631..634 refused. */
static void test_plan_then(struct rig *r, const pymb_plan_request *refused)
{
    uint16_t regs[22];
    double values[2];
    uint8_t states[2];
    pymb_map_entry e[2];
    pymbi_map_job job;
    pymbi_plan plan;
    pymb_failure fail;

    memset(e, 0, sizeof e);
    e[0].type = PYMB_MAP_U16; /* the first request's first register */
    e[1].type = PYMB_MAP_U16; /* the third's first */
    e[0].count = e[1].count = 1;
    e[0].channels = e[1].channels = 1;
    e[1].first = 20;
    e[1].out = 1;
    pymb_map_order("AB", 2, e[0].order);
    pymb_map_order("AB", 2, e[1].order);
    memset(&job, 0, sizeof job);
    memset(regs, 0, sizeof regs);
    job.entries = e;
    job.nentries = 2;
    job.regs = regs;
    job.nregs = 22;
    job.out.values = values;
    job.out.states = states;
    job.out.len = 2;
    CHECK(pymbi_map_ready(&job) == 2 && values[0] == 0.0);
    memset(&plan, 0, sizeof plan);
    plan.reqs = refused;
    plan.n = 3;
    plan.regs = regs;
    plan.nregs = 22;
    plan.then = &job;
    r->dev->param = 0;
    r->dev->state = 0;
    rig_start(r, answer_hub);
    errno = 0;
    CHECK(pymbi_plan_run(r->line, &plan, 0, &fail) == -1 && errno == EMBXILADD &&
          plan.done == 1 && plan.decoded == 0 && values[0] == 0.0);
    CHECK(pymbi_plan_run(r->line, &plan, plan.done + 1, &fail) == 0 && plan.done == 1 &&
          plan.decoded == 1 && values[0] == 31.0 && values[1] == 40.0);
    regs[0] = 7; /* the next run reads it again, and decodes what it read */
    CHECK(pymbi_plan_run(r->line, &plan, 2, &fail) == 0 && plan.decoded == 1 &&
          values[0] == 7.0 && values[1] == 40.0);
    plan.then = NULL;
    CHECK(pymbi_plan_run(r->line, &plan, 2, &fail) == 0 && plan.decoded == 0);
    CHECK(pymbi_plan_run(r->line, &plan, 3, &fail) == 0 && plan.done == 0);
    plan.line = r->line; /* pymbi_plan_go: the run from request 0 on the plan's line */
    plan.fail = &fail;
    errno = 0;
    CHECK(pymbi_plan_go(&plan) == -1 && errno == EMBXILADD && plan.done == 1 &&
          plan.decoded == 0 && fail.address == 625);
    rig_stop(r);
    errno = 0;
    CHECK(pymbi_plan_run(r->line, &plan, 4, &fail) == -1 && errno == EINVAL &&
          plan.done == 0 && plan.decoded == 0);
    CHECK(pymbi_plan_run(r->line, NULL, 0, &fail) == -1 && errno == EINVAL);
    errno = 0;
    CHECK(pymbi_plan_go(NULL) == -1 && errno == EINVAL);
}

/* pymb_read_plan: a whole plan in one call, its silences, its stop at the
 * first refusal (and the rest run from the one after), its checks. */
static void test_plan(enum kind k)
{
    struct rig r;
    uint16_t regs[140];
    pymb_failure fail;
    size_t done = 99;
    int unit = mbap(k) ? 0 : 250;
    double t0;
    pymb_plan_request plan[3] = {
        {MODBUS_FC_READ_HOLDING_REGISTERS, 0, 31, 3, 0},
        {MODBUS_FC_READ_INPUT_REGISTERS, 0, 100, 125, 3},
        {MODBUS_FC_READ_HOLDING_REGISTERS, 0, 500, 2, 128},
    };
    pymb_plan_request refused[3] = {
        {MODBUS_FC_READ_HOLDING_REGISTERS, 0, 31, 10, 0},
        {MODBUS_FC_READ_HOLDING_REGISTERS, 0, 625, 10, 10}, /* 631..634: exception 02 */
        {MODBUS_FC_READ_HOLDING_REGISTERS, 0, 40, 2, 20},
    };
    size_t i;

    for (i = 0; i < 3; i++) {
        plan[i].slave = (uint8_t)unit;
        refused[i].slave = (uint8_t)unit;
    }
    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    rig_start(&r, answer_reads);
    {
        /* The last of the three requests on the wire: 03, address 500, 2. */
        const uint8_t pdu[] = {0x03, 0x01, 0xF4, 0x00, 0x02};
        memset(regs, 0xEE, sizeof regs);
        CHECK(pymb_read_plan(r.line, plan, 3, 0, regs, 140, &done, &fail) == 0);
        CHECK(done == 3 && r.dev->requests == 3);
        CHECK(last_request_is(&r, 3, unit, pdu, sizeof pdu));
        CHECK(regs[0] == 1031 && regs[2] == 1033 && regs[3] == 1100 && regs[127] == 1224 &&
              regs[128] == 1500 && regs[129] == 1501 && regs[130] == 0xEEEE);
    }
    /* 25 ms of silence between requests: two silences in a plan of three. */
    t0 = now_s();
    CHECK(pymb_read_plan(r.line, plan, 3, 25000, regs, 140, &done, &fail) == 0 && done == 3);
    CHECK(now_s() - t0 >= 0.050);
    /* Refused arguments send nothing: a bad function, count, offset. */
    r.dev->requests = 0;
    {
        pymb_plan_request bad = plan[2];
        bad.function = 0x01;
        errno = 0;
        CHECK(pymb_read_plan(r.line, &bad, 1, 0, regs, 140, &done, &fail) == -1 &&
              errno == EINVAL && done == 0);
        bad = plan[2];
        bad.count = 126;
        CHECK(pymb_read_plan(r.line, &bad, 1, 0, regs, 140, &done, &fail) == -1 &&
              errno == EINVAL);
        bad = plan[2];
        bad.offset = 139; /* 139 + 2 > 140 */
        CHECK(pymb_read_plan(r.line, plan, 2, 0, regs, 140, &done, &fail) == 0 && done == 2);
        r.dev->requests = 0;
        plan[2] = bad;
        CHECK(pymb_read_plan(r.line, plan, 3, 0, regs, 140, &done, &fail) == -1 &&
              errno == EINVAL && done == 0);
        plan[2].offset = 128;
        bad = plan[0];
        bad.address = 65535; /* 65535 + 3 > 65536 */
        CHECK(pymb_read_plan(r.line, &bad, 1, 0, regs, 140, &done, &fail) == -1 &&
              errno == EINVAL);
        bad = plan[0];
        bad.offset = UINT32_MAX;
        CHECK(pymb_read_plan(r.line, &bad, 1, 0, regs, 140, &done, &fail) == -1 &&
              errno == EINVAL);
        CHECK(pymb_read_plan(r.line, NULL, 1, 0, regs, 140, &done, &fail) == -1 &&
              errno == EINVAL);
        CHECK(pymb_read_plan(NULL, plan, 1, 0, regs, 140, &done, &fail) == -1 &&
              errno == EINVAL);
        CHECK(pymb_read_plan(r.line, plan, 0, 0, regs, 140, &done, &fail) == 0 && done == 0);
        CHECK(r.dev->requests == 0);
    }
    rig_stop(&r);
    /* Exception 02 on the second request: it says which, keeps the first's
     * registers, and the rest runs from the one after. */
    r.dev->param = 0;
    r.dev->state = 0;
    rig_start(&r, answer_hub);
    memset(regs, 0, sizeof regs);
    errno = 0;
    CHECK(pymb_read_plan(r.line, refused, 3, 0, regs, 140, &done, &fail) == -1 &&
          errno == EMBXILADD && done == 1);
    CHECK(fail.function == 0x03 && fail.address == 625 && fail.count == 10);
    CHECK(regs[0] == 31 && regs[9] == 40 && regs[10] == 0 && regs[20] == 0);
    CHECK(pymb_read_plan(r.line, refused + done + 1, 3 - done - 1, 0, regs, 140, NULL,
                         &fail) == 0);
    CHECK(regs[20] == 40 && regs[21] == 41);
    rig_stop(&r);
    test_plan_then(&r, refused);
    rig_close(&r);
    printf("%s: read plan\n", kind_name(k));
}

static void test_signals(enum kind k)
{
    struct rig r;
    struct sigaction sa;
    uint16_t regs[2];
    pymb_failure fail;
    int calls = 0;
    double t0;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGUSR1, &sa, NULL); /* no SA_RESTART: poll is interrupted */
    modbus_set_response_timeout(r.ctx, 3, 0);

    /* The hook asks to stop: EINTR at once, not after the 3 s timeout. */
    got_signal = 0;
    pymb_line_set_interrupt(r.line, stop_on_signal, &calls);
    rig_start(&r, answer_signal_silence);
    t0 = now_s();
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 3, 0, 2, regs, &fail) ==
          -1 && errno == EINTR);
    CHECK(now_s() - t0 < 2.0 && got_signal && calls >= 1);
    rig_stop(&r);

    /* The hook lets it pass: the request goes on and takes its reply. The
     * stopped request left a quiet window owed (as long as the timeout):
     * a short timeout keeps it short. */
    modbus_set_response_timeout(r.ctx, 0, 300000);
    got_signal = 0;
    calls = 0;
    pymb_line_set_interrupt(r.line, never_stop, &calls);
    rig_start(&r, answer_signal_then_reply);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 3, 0, 2, regs, &fail) ==
          2 && regs[1] == 1001);
    CHECK(got_signal && calls >= 1);
    rig_stop(&r);

    /* No hook: a signal never stops a request. */
    got_signal = 0;
    pymb_line_set_interrupt(r.line, NULL, NULL);
    rig_start(&r, answer_signal_then_reply);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 3, 0, 2, regs, &fail) ==
          2 && regs[0] == 1000);
    CHECK(got_signal);
    rig_stop(&r);
    signal(SIGUSR1, SIG_DFL);
    rig_close(&r);
    printf("%s: signals\n", kind_name(k));
}

static void test_unknown_length_and_broadcast(enum kind k)
{
    struct rig r;
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    pymb_failure fail;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    /* A user function code (0x41): the reply ends by the line's silence
     * (RTU) or by the MBAP length (TCP). */
    rig_start(&r, answer_user_function);
    {
        const uint8_t req[] = {12, 0x41, 0x01};
        int h = pymb_line_header_length(r.line);
        CHECK(pymb_transact(r.line, req, sizeof req, 0, rsp, sizeof rsp, &fail) == 4);
        CHECK(rsp[h] == 0x41 && rsp[h + 1] == 0xAA && rsp[h + 3] == 0xCC);
        CHECK(last_request_is(&r, 1, 12, req + 1, 2));
        /* Told the length, a shorter reply is not taken. */
        errno = 0;
        CHECK(pymb_transact(r.line, req, sizeof req, 6, rsp, sizeof rsp, &fail) == -1 &&
              errno == EMBBADDATA && fail.frame == PYMB_FRAME_BAD_LENGTH);
    }
    rig_stop(&r);
    if (!mbap(k)) {
        /* Address 0 is a broadcast: sent, no reply awaited. */
        const uint8_t req[] = {0, 0x06, 0x00, 0x01, 0x00, 0x03};
        uint16_t regs[1];
        rig_start(&r, NULL);
        CHECK(pymb_transact(r.line, req, sizeof req, 0, rsp, sizeof rsp, &fail) == 0);
        CHECK(r.dev->requests == 1); /* it came during the turnaround delay */
        CHECK(last_request_is(&r, 0, 0, req + 1, 5));
        /* A read needs an answer: never to address 0. */
        errno = 0;
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 0, 0, 1, regs,
                                  &fail) == -1 && errno == EINVAL);
        rig_stop(&r);
    }
    rig_close(&r);
    printf("%s: unknown reply length, broadcast\n", kind_name(k));
}

/* An I/O in place of the socket's own (pymb_line_set_io): it takes all the
 * socket has into its own buffer and hands out one byte a read, as TLS
 * hands out decrypted bytes, so the line must ask `pending` before it waits
 * on the descriptor (the bytes are no longer there). */
struct chunky {
    int fd;
    uint8_t buf[600];
    int have, at;
    int reads, writes;
};

static int chunky_read(void *arg, uint8_t *out, int n)
{
    struct chunky *c = arg;
    c->reads++;
    if (c->at == c->have) {
        ssize_t k = read(c->fd, c->buf, sizeof c->buf);
        if (k < 0) {
            return -errno;
        }
        if (k == 0) {
            return 0;
        }
        c->have = (int)k;
        c->at = 0;
    }
    if (n < 1) {
        return -EINVAL;
    }
    out[0] = c->buf[c->at++];
    return 1;
}

static int chunky_write(void *arg, const uint8_t *b, int n)
{
    struct chunky *c = arg;
    c->writes++;
    return send(c->fd, b, (size_t)n, MSG_NOSIGNAL) == n ? 0 : -EIO;
}

static int chunky_pending(void *arg)
{
    const struct chunky *c = arg;
    return c->have - c->at;
}

static void test_io(enum kind k)
{
    struct rig r;
    struct chunky c;
    pymb_line_io io = {chunky_read, chunky_write, chunky_pending, &c};
    uint16_t regs[4];
    pymb_failure fail;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    memset(&c, 0, sizeof c);
    c.fd = modbus_get_socket(r.ctx);
    fcntl(c.fd, F_SETFL, fcntl(c.fd, F_GETFL) | O_NONBLOCK);
    CHECK(pymb_line_set_io(r.line, &io) == 0);
    rig_start(&r, answer_reads);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 7, 4, 3, regs, &fail) ==
          3 && regs[0] == 1004 && regs[2] == 1006);
    CHECK(c.writes == 1 && c.reads >= 11 && c.at == c.have);
    rig_stop(&r);
    if (k == TCP) {
        /* A reply to an older transaction comes first, in the same chunk:
         * dropped by its id, the answer taken from the I/O's buffer. */
        rig_start(&r, answer_old_tid_first);
        CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 7, 0, 2, regs,
                                  &fail) == 2 && regs[0] == 1000);
        rig_stop(&r);
    }
    /* The socket's own I/O again. */
    CHECK(pymb_line_set_io(r.line, NULL) == 0);
    c.reads = c.writes = 0;
    rig_start(&r, answer_reads);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 7, 0, 1, regs, &fail) ==
          1 && regs[0] == 1000 && c.reads == 0 && c.writes == 0);
    rig_stop(&r);
    /* A stream the I/O says has ended is a closed peer. */
    CHECK(pymb_line_set_io(r.line, &io) == 0);
    c.have = c.at = 0;
    shutdown(r.dev->fd, SHUT_WR);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 7, 0, 1, regs, &fail) ==
          -1 && errno == ECONNRESET);
    rig_close(&r);
    printf("%s: I/O callbacks\n", kind_name(k));
}

/* The ASCII frame by itself ([MB-SL] 2.5.2): the LRC, the text, and the
 * receiver's refusals, against the test's own encoder. */
static int feed_all(pymbi_ascii_rx *rx, const char *text, size_t n)
{
    size_t i;
    int rc = PYMB_FRAME_INCOMPLETE;
    for (i = 0; i < n; i++) {
        rc = pymbi_ascii_feed(rx, (uint8_t)text[i]);
        if (rc != PYMB_FRAME_INCOMPLETE && i + 1 < n) {
            return -100; /* ended before its last character */
        }
    }
    return rc;
}

static void test_ascii_frame(void)
{
    /* Read 10 holding registers from 0 at address 1: LRC 0xF2. */
    const uint8_t req[] = {0x01, 0x03, 0x00, 0x00, 0x00, 0x0A};
    const char want[] = ":01030000000AF2\r\n";
    uint8_t out[PYMB_ASCII_MAX_TEXT], big[PYMB_MAX_PDU + 2], text[PYMB_ASCII_MAX_TEXT + 8];
    pymbi_ascii_rx rx;
    size_t i;
    int n, exc = 0;

    CHECK(pymbi_ascii_lrc(req, sizeof req) == 0xF2 && lrc_ref(req, sizeof req) == 0xF2);
    CHECK(pymbi_ascii_lrc(req, 0) == 0);
    n = pymbi_ascii_encode(req, (int)sizeof req, out, (int)sizeof out);
    CHECK(n == (int)strlen(want) && memcmp(out, want, strlen(want)) == 0);
    CHECK(pymbi_ascii_encode(req, 1, out, (int)sizeof out) == -1);
    CHECK(pymbi_ascii_encode(req, (int)sizeof req, out, 16) == -1); /* 17 needed */
    CHECK(pymbi_ascii_encode(req, (int)sizeof req, out, 17) == 17);
    for (i = 0; i < sizeof big; i++) {
        big[i] = (uint8_t)(i * 7u);
    }
    CHECK(pymbi_ascii_encode(big, 1 + PYMB_MAX_PDU, out, (int)sizeof out) ==
          PYMB_ASCII_MAX_TEXT);
    CHECK(pymbi_ascii_encode(big, 2 + PYMB_MAX_PDU, out, (int)sizeof out) == -1);

    /* A whole frame, after noise, in either case. */
    memset(&rx, 0, sizeof rx);
    CHECK(feed_all(&rx, "xx\r\n:01030000000AF2\r\n", strlen("xx\r\n:01030000000AF2\r\n")) == 7);
    CHECK(memcmp(rx.out, req, sizeof req) == 0 && rx.out[6] == 0xF2);
    memset(&rx, 0, sizeof rx);
    CHECK(feed_all(&rx, ":01030000000af2\r\n", strlen(":01030000000af2\r\n")) == 7 && rx.out[6] == 0xF2);
    /* A ':' starts again: the frame before it is gone. */
    memset(&rx, 0, sizeof rx);
    CHECK(feed_all(&rx, ":0103:01030000000AF2\r\n", strlen(":0103:01030000000AF2\r\n")) == 7);
    /* Refused: an odd digit count, a non-digit (the bytes before it kept),
     * CR without LF, too short. */
    memset(&rx, 0, sizeof rx);
    CHECK(feed_all(&rx, ":01030000000AF\r\n", strlen(":01030000000AF\r\n")) == PYMB_FRAME_BAD_TEXT);
    CHECK(feed_all(&rx, ":0103000G000AF2\r\n", strlen(":0103000G000AF2\r\n")) == PYMB_FRAME_BAD_TEXT);
    CHECK(rx.nhex == 7 && rx.out[0] == 0x01 && rx.out[1] == 0x03 && rx.out[2] == 0x00);
    CHECK(feed_all(&rx, ":01030000000AF2\rX", strlen(":01030000000AF2\rX")) == PYMB_FRAME_BAD_TEXT);
    CHECK(feed_all(&rx, ":01030000000AF2\n\r\n", strlen(":01030000000AF2\n\r\n")) ==
          PYMB_FRAME_BAD_TEXT);
    CHECK(feed_all(&rx, ":0100\r\n", strlen(":0100\r\n")) == PYMB_FRAME_BAD_LENGTH);
    /* After a refusal, the next frame is whole again. */
    CHECK(feed_all(&rx, ":01030000000AF2\r\n", strlen(":01030000000AF2\r\n")) == 7);
    /* Longer than any frame: refused as soon as it is. */
    memset(&rx, 0, sizeof rx);
    text[0] = ':';
    memset(text + 1, '0', PYMB_ASCII_MAX_TEXT + 4);
    n = PYMB_FRAME_INCOMPLETE;
    for (i = 0; i < PYMB_ASCII_MAX_TEXT + 5 && n == PYMB_FRAME_INCOMPLETE; i++) {
        n = pymbi_ascii_feed(&rx, text[i]);
    }
    CHECK(n == PYMB_FRAME_TOO_LONG && i == 1 + 2 * PYMB_ASCII_MAX_BYTES + 1);
    /* The longest frame passes. */
    n = pymbi_ascii_encode(big, 1 + PYMB_MAX_PDU, out, (int)sizeof out);
    memset(&rx, 0, sizeof rx);
    CHECK(feed_all(&rx, (const char *)out, (size_t)n) == PYMB_ASCII_MAX_BYTES);

    /* The checks of a decoded reply: LRC, address, PDU, exception. */
    {
        uint8_t f[] = {0x01, 0x03, 0x02, 0x12, 0x34, 0};
        uint8_t e[] = {0x01, 0x83, 0x02, 0};
        f[5] = lrc_ref(f, 5);
        e[3] = lrc_ref(e, 3);
        const uint8_t one[] = {0x01, 0x03, 0x00, 0x00, 0x00, 0x01};
        CHECK(pymbi_ascii_check(one, 6, f, 6, &exc) == PYMB_FRAME_OK);
        f[5] ^= 1;
        CHECK(pymbi_ascii_check(one, 6, f, 6, &exc) == PYMB_FRAME_BAD_CRC);
        f[5] ^= 1;
        f[0] = 2;
        f[5] = lrc_ref(f, 5);
        CHECK(pymbi_ascii_check(one, 6, f, 6, &exc) == PYMB_FRAME_BAD_SLAVE);
        CHECK(pymbi_ascii_check(one, 6, e, 4, &exc) == PYMB_FRAME_EXCEPTION && exc == 2);
        CHECK(pymbi_ascii_check(one, 6, e, 2, &exc) == PYMB_FRAME_INVALID);
    }
    printf("ASCII: frame, LRC, receiver\n");
}

/* ASCII's inter-character timeout: 1 s when the byte timeout is 0. A gap
 * of 0.4 s inside a frame is kept; one of 1.2 s drops the frame begun, and
 * the whole frame that follows is the answer. */
static void answer_ascii_gaps(struct dev *d, const uint8_t *req, int n)
{
    uint8_t out[64];
    const uint8_t slow[] = {0x03, 0x02, 0x00, 0x07};
    const uint8_t fine[] = {0x03, 0x02, 0x00, 0x08};
    size_t len = frame(d->kind, 0, req[0], slow, sizeof slow, out);
    (void)n;
    dev_send(d, out, 5);
    sleep_ms(d->param);
    dev_send(d, out + 5, len - 5);
    len = frame(d->kind, 0, req[0], fine, sizeof fine, out);
    dev_send(d, out, len);
}

static void test_ascii_char_timeout(void)
{
    struct rig r;
    uint16_t regs[1];
    pymb_failure fail;

    if (rig_open(&r, ASCII) != 0) {
        failures++;
        return;
    }
    modbus_set_response_timeout(r.ctx, 4, 0);
    r.dev->param = 400;
    rig_start(&r, answer_ascii_gaps);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 0, 1, regs, &fail) ==
          1 && regs[0] == 7);
    rig_stop(&r);
    sleep_ms(100); /* the second frame of that script, unread, is flushed */
    r.dev->param = 1200;
    rig_start(&r, answer_ascii_gaps);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 0, 1, regs, &fail) ==
          1 && regs[0] == 8);
    rig_stop(&r);
    rig_close(&r);
    printf("ASCII: inter-character timeout\n");
}

/* [MB-SL] 2.4.1: a reply from another address is not the answer; the
 * device asked may still answer after it. The first request gets a frame
 * from address 9 and then, 20 ms later, its own answer (1000 + address); the
 * next request (another address: 2000 + address) must never take that
 * answer as its own. */
static void answer_other_first(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t pdu[] = {0x03, 0x02, 0x00, 0x09};
    uint8_t out[64];
    size_t len;

    (void)n;
    if (d->state++ == 0) {
        len = frame(d->kind, 0, 9, pdu, sizeof pdu, out);
        dev_send(d, out, len);
        sleep_ms(20);
        dev_read_reply(d, req, 1000);
        return;
    }
    dev_read_reply(d, req, 2000);
}

static void test_ascii_other_address(void)
{
    struct rig r;
    uint16_t regs[1];
    pymb_failure fail;

    if (rig_open(&r, ASCII) != 0) {
        failures++;
        return;
    }
    modbus_set_response_timeout(r.ctx, 0, 300000);
    rig_start(&r, answer_other_first);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 5, 1, regs, &fail) ==
          -1 && errno == EMBBADSLAVE && fail.frame == PYMB_FRAME_BAD_SLAVE);
    regs[0] = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 5, 1, regs, &fail) ==
          1 && regs[0] == 2005);
    rig_stop(&r);
    rig_close(&r);
    printf("ASCII: a frame from another address, then the answer\n");
}

/* [MB-SL] 2.4.1: an error detected on a frame fails the request at once;
 * the device answered, badly. Request 0 gets a frame with a character that
 * is no hexadecimal digit, request 1 one longer than any frame, request 2
 * its answer; request 3 the start of a frame that then stops (the
 * inter-character timeout drops it, and the timeout says what it had). Each
 * goes to another address: a bad frame owes its address a quiet window. */
static void answer_ascii_garbled(struct dev *d, const uint8_t *req, int n)
{
    static const char garbled[] = ":0103Z2000501\r\n";
    uint8_t out[700];
    int i;

    (void)n;
    switch (d->state++) {
    case 0:
        dev_send(d, (const uint8_t *)garbled, strlen(garbled));
        break;
    case 1:
        out[0] = ':';
        for (i = 1; i < 601; i++) {
            out[i] = '0';
        }
        out[601] = '\r';
        out[602] = '\n';
        dev_send(d, out, 603);
        break;
    case 2:
        dev_read_reply(d, req, 2000);
        break;
    default:
        dev_send(d, (const uint8_t *)":010302", 7);
        break;
    }
}

static void test_ascii_bad_frames(void)
{
    struct rig r;
    uint16_t regs[1];
    pymb_failure fail;
    double t0;

    if (rig_open(&r, ASCII) != 0) {
        failures++;
        return;
    }
    modbus_set_response_timeout(r.ctx, 1, 0);
    rig_start(&r, answer_ascii_garbled);
    t0 = now_s();
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 5, 1, regs, &fail) ==
          -1 && errno == EMBBADDATA && fail.frame == PYMB_FRAME_BAD_TEXT && fail.rsp_len == 2 &&
          fail.rsp[0] == 0x01 && fail.rsp[1] == 0x03);
    CHECK(now_s() - t0 < 0.8);
    t0 = now_s();
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 2, 5, 1, regs, &fail) ==
          -1 && errno == EMBBADDATA && fail.frame == PYMB_FRAME_TOO_LONG);
    CHECK(now_s() - t0 < 0.8);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 3, 5, 1, regs, &fail) ==
          1 && regs[0] == 2005);
    modbus_set_response_timeout(r.ctx, 0, 500000);
    modbus_set_byte_timeout(r.ctx, 0, 100000);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 4, 5, 1, regs, &fail) ==
          -1 && errno == ETIMEDOUT && fail.frame == PYMB_FRAME_INCOMPLETE && fail.rsp_len == 3 &&
          fail.rsp[0] == 0x01 && fail.rsp[1] == 0x03 && fail.rsp[2] == 0x02);
    rig_stop(&r);
    rig_close(&r);
    printf("ASCII: a garbled frame, one too long, one that stops\n");
}

/* Modbus TCP: a reply that stops part-way (in its MBAP header, then in its
 * PDU) times out, and the failure keeps the bytes that came (they say the
 * device did answer); then an honest reply is taken. */
static void answer_tcp_cut(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t pdu[] = {0x03, 0x02, 0x00, 0x07};
    uint8_t out[64];
    size_t len = frame(d->kind, req_tid(d, req), req_unit(d, req), pdu, sizeof pdu, out);
    int state = d->state++;

    (void)n;
    dev_send(d, out, state == 0 ? 5 : state == 1 ? 8 : len);
}

static void test_tcp_cut_short(void)
{
    struct rig r;
    uint16_t regs[1];
    pymb_failure fail;

    if (rig_open(&r, TCP) != 0) {
        failures++;
        return;
    }
    rig_start(&r, answer_tcp_cut);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 0, 1, regs, &fail) ==
          -1 && errno == ETIMEDOUT && fail.frame == PYMB_FRAME_INCOMPLETE && fail.rsp_len == 5);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 2, 0, 1, regs, &fail) ==
          -1 && errno == ETIMEDOUT && fail.frame == PYMB_FRAME_INCOMPLETE && fail.rsp_len == 8 &&
          fail.rsp[6] == 2 && fail.rsp[7] == 0x03);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 3, 0, 1, regs, &fail) ==
          1 && regs[0] == 7);
    rig_stop(&r);
    rig_close(&r);
    printf("TCP: a reply cut short\n");
}

/* RTU: a whole frame, its CRC right, whose byte count says more data than
 * it carries (4 bytes for 1 register, with 2): the wait for the rest ends at
 * the timeout, and the frame is refused for its length, not as a timeout.
 * Then one whose byte count says less (1): its CRC fails where the count
 * ends it, but is right over all it sent: refused for its length too. */
static void answer_count_lie(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t more[] = {0x03, 0x04, 0x00, 0x07};
    const uint8_t less[] = {0x03, 0x01, 0x00, 0x07};
    (void)n;
    if (d->state++ == 0) {
        dev_reply(d, req, more, sizeof more);
    } else {
        dev_reply(d, req, less, sizeof less);
    }
}

static void test_rtu_count_lie(enum kind k)
{
    struct rig r;
    uint16_t regs[1];
    pymb_failure fail;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    rig_start(&r, answer_count_lie);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 0, 1, regs, &fail) ==
          -1 && errno == EMBBADDATA && fail.frame == PYMB_FRAME_BAD_LENGTH && fail.rsp_len == 7);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 2, 0, 1, regs, &fail) ==
          -1 && errno == EMBBADDATA && fail.frame == PYMB_FRAME_BAD_LENGTH);
    rig_stop(&r);
    rig_close(&r);
    printf("%s: a byte count that says more, or less, than the frame\n", kind_name(k));
}

/* [MB-TCP] 3.1.3: a device that answers with transaction id 0 whatever
 * the request's (it does not echo the id): its replies are not answers, and
 * the timeout shows the last one (not "nothing came"). */
static void answer_tid_zero(struct dev *d, const uint8_t *req, int n)
{
    const uint8_t pdu[] = {0x03, 0x02, 0x00, 0x07};
    uint8_t out[64];
    size_t len = frame(d->kind, 0, req_unit(d, req), pdu, sizeof pdu, out);
    (void)n;
    dev_send(d, out, len);
}

static void test_tid_not_echoed(enum kind k)
{
    struct rig r;
    uint16_t regs[1];
    pymb_failure fail;

    if (rig_open(&r, k) != 0) {
        failures++;
        return;
    }
    rig_start(&r, answer_tid_zero);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 0, 1, regs, &fail) ==
          -1 && errno == ETIMEDOUT && fail.frame == PYMB_FRAME_BAD_TID && fail.rsp_len == 11 &&
          fail.rsp[0] == 0 && fail.rsp[1] == 0);
    rig_stop(&r);
    rig_close(&r);
    printf("%s: replies that do not echo the transaction id\n", kind_name(k));
}

/* UDP: the first datagram of each request is lost (not answered); the
 * resend, with the same transaction id, is. */
static void answer_every_second(struct dev *d, const uint8_t *req, int n)
{
    (void)n;
    if (d->state++ % 2 == 1) {
        dev_read_reply(d, req, 1000);
    }
}

static void test_udp_retries(void)
{
    struct rig r;
    uint16_t regs[2];
    pymb_failure fail;
    uint8_t first[300];
    int first_len;

    if (rig_open(&r, UDP) != 0) {
        failures++;
        return;
    }
    modbus_set_response_timeout(r.ctx, 0, 100000);
    rig_start(&r, answer_every_second);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 4, 0, 2, regs, &fail) ==
          -1 && errno == ETIMEDOUT && r.dev->requests == 1); /* no retries by default */
    rig_stop(&r);
    r.dev->state = 0;
    CHECK(pymb_line_set_retries(r.line, 1) == 0);
    rig_start(&r, answer_every_second);
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 4, 0, 2, regs, &fail) ==
          2 && regs[1] == 1001 && r.dev->requests == 2);
    first_len = r.dev->last_len;
    memcpy(first, r.dev->last, (size_t)first_len);
    {
        /* Each send of the request is the same datagram: transaction 2. */
        const uint8_t pdu[] = {0x03, 0x00, 0x00, 0x00, 0x02};
        CHECK(last_request_is(&r, 2, 4, pdu, sizeof pdu));
    }
    rig_stop(&r);
    /* Never answered: retries + 1 sends, then ETIMEDOUT. */
    CHECK(pymb_line_set_retries(r.line, 2) == 0);
    rig_start(&r, NULL);
    errno = 0;
    CHECK(pymb_read_registers(r.line, MODBUS_FC_READ_HOLDING_REGISTERS, 4, 0, 2, regs, &fail) ==
          -1 && errno == ETIMEDOUT);
    CHECK(r.dev->requests == 3);
    rig_stop(&r);
    rig_close(&r);
    printf("UDP: retries\n");
}

/* pymb_line_connect opens a UDP line's own socket: a device on a real
 * 127.0.0.1 port answers through it; pymb_line_close closes it. */
static void test_udp_connect(void)
{
    struct sockaddr_in sa;
    socklen_t len = sizeof sa;
    char port[16];
    int dev = socket(AF_INET, SOCK_DGRAM, 0);
    modbus_t *ctx;
    pymb_line *line;
    uint16_t regs[1];
    pid_t child;

    memset(&sa, 0, sizeof sa);
    sa.sin_family = AF_INET;
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    CHECK(dev >= 0 && bind(dev, (struct sockaddr *)&sa, sizeof sa) == 0 &&
          getsockname(dev, (struct sockaddr *)&sa, &len) == 0);
    snprintf(port, sizeof port, "%u", (unsigned)ntohs(sa.sin_port));
    fflush(NULL);
    child = fork();
    if (child == 0) {
        uint8_t q[300], a[32];
        struct sockaddr_in from;
        socklen_t flen = sizeof from;
        struct pollfd p = {dev, POLLIN, 0};
        ssize_t n;
        if (poll(&p, 1, 5000) <= 0) {
            _exit(1);
        }
        n = recvfrom(dev, q, sizeof q, 0, (struct sockaddr *)&from, &flen);
        if (n != 12) {
            _exit(1);
        }
        memcpy(a, q, 7);
        a[5] = 5;   /* unit + 4 bytes of PDU */
        a[7] = 0x03;
        a[8] = 2;
        a[9] = 0x12;
        a[10] = 0x34;
        sendto(dev, a, 11, 0, (struct sockaddr *)&from, flen);
        _exit(0);
    }
    ctx = modbus_new_tcp_pi("127.0.0.1", port);
    line = pymb_line_new(ctx, PYMB_FRAMING_UDP, 0);
    CHECK(line != NULL);
    modbus_set_response_timeout(ctx, 3, 0);
    errno = 0;
    CHECK(pymb_line_connect(line, NULL, port) == -1 && errno == EINVAL);
    CHECK(pymb_line_connect(line, "127.0.0.1", port) == 0 && modbus_get_socket(ctx) >= 0);
    CHECK(pymb_line_connect(line, "127.0.0.1", port) == 0); /* open already */
    CHECK(pymb_read_registers(line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 0, 1, regs, NULL) == 1 &&
          regs[0] == 0x1234);
    pymb_line_close(line);
    CHECK(modbus_get_socket(ctx) == -1);
    pymb_line_close(line); /* twice: nothing */
    errno = 0;
    CHECK(pymb_read_registers(line, MODBUS_FC_READ_HOLDING_REGISTERS, 1, 0, 1, regs, NULL) ==
          -1 && errno == EINVAL);
    waitpid(child, NULL, 0);
    pymb_line_free(line);
    modbus_free(ctx);
    close(dev);
    printf("UDP: connect, close\n");
}

static void test_arguments(void)
{
    struct rig r;
    uint16_t regs[4];
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    const uint8_t req[] = {1, 0x03, 0, 0, 0, 1};
    pymb_failure fail;

    if (rig_open(&r, TCP) != 0) {
        failures++;
        return;
    }
    /* A line for the wrong kind of context, an unknown framing. */
    errno = 0;
    CHECK(pymb_line_new(r.ctx, PYMB_FRAMING_RTU, 0) == NULL && errno == EINVAL);
    CHECK(pymb_line_new(r.ctx, (pymb_framing)9, 0) == NULL && errno == EINVAL);
    CHECK(pymb_line_new(NULL, PYMB_FRAMING_TCP, 0) == NULL && errno == EINVAL);
    pymb_line_free(NULL);
    CHECK(pymb_line_set_interrupt(NULL, NULL, NULL) == -1 && errno == EINVAL);
    CHECK(pymb_line_set_char_ns(NULL, 1) == -1 && errno == EINVAL);
    CHECK(pymb_line_set_io(NULL, NULL) == -1 && errno == EINVAL);
    {
        pymb_line_io partial = {NULL, NULL, NULL, NULL};
        errno = 0;
        CHECK(pymb_line_set_io(r.line, &partial) == -1 && errno == EINVAL);
    }
    CHECK(pymb_line_header_length(NULL) == -1 && errno == EINVAL);
    CHECK(pymb_line_new(r.ctx, PYMB_FRAMING_ASCII, 0) == NULL && errno == EINVAL);
    CHECK(pymb_line_set_retries(NULL, 1) == -1 && errno == EINVAL);
    CHECK(pymb_line_set_retries(r.line, -1) == -1 && errno == EINVAL);
    CHECK(pymb_line_set_retries(r.line, PYMB_MAX_RETRIES + 1) == -1 && errno == EINVAL);
    CHECK(pymb_line_set_retries(r.line, PYMB_MAX_RETRIES) == 0);
    CHECK(pymb_line_connect(NULL, NULL, NULL) == -1 && errno == EINVAL);
    pymb_line_close(NULL);
    /* Refused before any I/O, the failure record reset all the same. */
    memset(&fail, 0x55, sizeof fail);
    errno = 0;
    CHECK(pymb_read_registers(NULL, 3, 1, 0, 1, regs, &fail) == -1 && errno == EINVAL);
    CHECK(fail.function == -1 && fail.address == -1 && fail.count == -1 && fail.rsp_len == 0);
    CHECK(pymb_read_registers(r.line, 0x05, 1, 0, 1, regs, &fail) == -1 && errno == EINVAL);
    CHECK(pymb_read_registers(r.line, 3, 256, 0, 1, regs, &fail) == -1 && errno == EINVAL);
    CHECK(pymb_read_registers(r.line, 3, 1, 65535, 2, regs, &fail) == -1 && errno == EINVAL);
    CHECK(pymb_read_registers(r.line, 3, 1, 0, 0, regs, &fail) == -1 && errno == EINVAL);
    CHECK(pymb_read_bits(r.line, 3, 1, 0, 1, rsp, &fail) == -1 && errno == EINVAL);
    CHECK(pymb_transact(r.line, req, 1, 0, rsp, sizeof rsp, &fail) == -1 && errno == EINVAL);
    CHECK(pymb_transact(r.line, req, sizeof req, 0, rsp, 10, &fail) == -1 && errno == EINVAL);
    CHECK(r.dev->requests == 0);
    rig_close(&r);
}

int main(void)
{
    static const enum kind kinds[] = {RTU, TCP, RTU_TCP, ASCII, UDP};
    size_t i;

    setvbuf(stdout, NULL, _IOLBF, 0); /* progress shows at once, also under qemu */
    alarm(600); /* bounded: a run that hangs is killed and fails */
    signal(SIGPIPE, SIG_IGN);
    test_arguments();
    test_ascii_frame();
    test_ascii_char_timeout();
    test_ascii_other_address();
    test_ascii_bad_frames();
    test_tcp_cut_short();
    test_rtu_count_lie(RTU);
    test_rtu_count_lie(RTU_TCP);
    test_tid_not_echoed(TCP);
    test_tid_not_echoed(UDP);
    test_udp_retries();
    test_udp_connect();
    for (i = 0; i < sizeof kinds / sizeof kinds[0]; i++) {
        test_reads(kinds[i]);
        test_exceptions(kinds[i]);
        test_split_and_bad(kinds[i]);
        test_late_and_stale(kinds[i]);
        test_plan(kinds[i]);
        test_signals(kinds[i]);
        test_unknown_length_and_broadcast(kinds[i]);
        if (kinds[i] == TCP || kinds[i] == RTU_TCP) { /* the stream sockets (TLS) */
            test_io(kinds[i]);
        }
    }
    return check_report();
}
