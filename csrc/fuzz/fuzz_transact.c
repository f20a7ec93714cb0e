/* SPDX-License-Identifier: MIT */
/*
 * fuzz_transact.c - libFuzzer target: pymb's request path (pymb_transact,
 * pymb_read_registers and pymb_read_plan, for any slave address 0..255,
 * and the extension's held plan that decodes after its reads, pymbi_plan_run)
 * over libmodbus and a real pseudo-terminal. The input is what the "device"
 * sends back: it is written to the pty's master side, then pymb makes one
 * request and must return either checked data or an error, never read
 * outside its buffers and never accept a frame that fails its checks.
 *
 * The first input byte picks the request (and, with bit 7, also puts the
 * reply on the line *before* the request, as stale data that pymb must
 * discard); the rest is the reply, sent after each request. Requests 4 and
 * 5 go over a socket pair instead: Modbus TCP (pymb's MBAP parsing, the
 * transaction id check) and RTU over TCP. In the plan's case, bit 6 runs
 * the plan again held (pymbi_plan_run): it decodes only when every read
 * has its reply, and then what was read.
 */
#define _XOPEN_SOURCE 700
#define _DEFAULT_SOURCE

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <sys/socket.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "../pymb_internal.h" /* the line's private state: owed, tid */

int LLVMFuzzerInitialize(int *argc, char ***argv);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int master_fd = -1;
static modbus_t *ctx;
static pymb_line *line;
static int sock_fd = -1; /* the "device" end of the socket pair */
static modbus_t *tcp_ctx;
static pymb_line *tcp_line, *rot_line;

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    struct termios tio;
    (void)argc;
    (void)argv;
    master_fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (master_fd < 0 || grantpt(master_fd) || unlockpt(master_fd)) {
        perror("pty");
        exit(1);
    }
    tcgetattr(master_fd, &tio);
    cfmakeraw(&tio);
    tcsetattr(master_fd, TCSANOW, &tio);
    fcntl(master_fd, F_SETFL, fcntl(master_fd, F_GETFL) | O_NONBLOCK);
    ctx = modbus_new_rtu(ptsname(master_fd), 115200, 'N', 8, 1);
    if (ctx == NULL || modbus_connect(ctx) == -1) {
        perror("modbus");
        exit(1);
    }
    modbus_set_response_timeout(ctx, 0, 3000);
    modbus_set_byte_timeout(ctx, 0, 0);
    line = pymb_line_new(ctx, PYMB_FRAMING_RTU, pymb_rtu_silence_us(115200));
    {
        int sp[2];
        if (socketpair(AF_UNIX, SOCK_STREAM, 0, sp) != 0) {
            perror("socketpair");
            exit(1);
        }
        fcntl(sp[0], F_SETFL, fcntl(sp[0], F_GETFL) | O_NONBLOCK);
        fcntl(sp[1], F_SETFL, fcntl(sp[1], F_GETFL) | O_NONBLOCK);
        sock_fd = sp[1];
        tcp_ctx = modbus_new_tcp("127.0.0.1", 502);
        if (tcp_ctx == NULL || modbus_set_socket(tcp_ctx, sp[0]) == -1) {
            perror("modbus tcp");
            exit(1);
        }
        modbus_set_response_timeout(tcp_ctx, 0, 3000);
        modbus_set_byte_timeout(tcp_ctx, 0, 0);
        tcp_line = pymb_line_new(tcp_ctx, PYMB_FRAMING_TCP, 0);
        rot_line = pymb_line_new(tcp_ctx, PYMB_FRAMING_RTU_OVER_TCP, 2000);
        if (line == NULL || tcp_line == NULL || rot_line == NULL) {
            perror("pymb_line_new");
            exit(1);
        }
    }
    return 0;
}

static void drain_master(void)
{
    uint8_t junk[512];
    while (read(master_fd, junk, sizeof junk) > 0) {
    }
    while (read(sock_fd, junk, sizeof junk) > 0) {
    }
    while (read(modbus_get_socket(tcp_ctx), junk, sizeof junk) > 0) {
    }
}

/* The device: answers every request it sees with the fuzz input. */
struct responder {
    int fd;
    const uint8_t *reply;
    size_t len;
    volatile int stop;
};

static void *respond(void *arg)
{
    struct responder *r = arg;
    uint8_t req[512];
    struct pollfd pfd = {.fd = r->fd, .events = POLLIN};

    while (!r->stop) {
        if (poll(&pfd, 1, 1) > 0 && read(r->fd, req, sizeof req) > 0 && r->len) {
            if (write(r->fd, r->reply, r->len) < 0 && errno != EAGAIN) {
                abort();
            }
        }
    }
    return NULL;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH + 8];
    uint16_t regs[700];
    pymb_failure fail;
    size_t reply = size > 1 ? size - 1 : 0;
    int which = size ? data[0] % 6 : 0, n;
    int dev_fd = which >= 4 ? sock_fd : master_fd;
    struct responder resp;
    pthread_t thread;

    if (reply > 600) {
        reply = 600;
    }
    drain_master();
    line->owed = 0;
    tcp_line->owed = 0;
    rot_line->owed = 0;
    pymb_flush(line);
    if ((size && (data[0] & 0x80)) && reply && write(dev_fd, data + 1, reply) < 0 &&
        errno != EAGAIN) {
        abort();
    }
    resp.fd = dev_fd;
    resp.reply = data + 1;
    resp.len = reply;
    resp.stop = 0;
    if (pthread_create(&thread, NULL, respond, &resp) != 0) {
        abort();
    }
    memset(&fail, 0, sizeof fail);
    switch (which) {
    case 0: { /* raw read of 3 registers from slave 250 */
        const uint8_t req[] = {250, 0x03, 0x00, 0x1F, 0x00, 0x03};
        n = pymb_transact(line, req, sizeof req, which == 0 && size > 2 && (data[1] & 1) ? 8 : 0, rsp, (int)sizeof rsp - 8, &fail);
        if (n >= 0 && (n != 8 || rsp[0] != 250 || !pymb_rtu_crc_ok(rsp, (size_t)n + 3))) {
            abort();
        }
        break;
    }
    case 1: { /* write single register, echo checked */
        const uint8_t req[] = {40, 0x06, 0x00, 0x00, 0x00, 0x2A};
        n = pymb_transact(line, req, sizeof req, which == 0 && size > 2 && (data[1] & 1) ? 8 : 0, rsp, (int)sizeof rsp - 8, &fail);
        if (n >= 0 && (n != 5 || memcmp(rsp, req, 6) != 0)) {
            abort();
        }
        break;
    }
    case 2: /* split read, slave 251 */
        n = pymb_read_registers(line, 3, 251, 31, 130, regs, &fail);
        if (n != -1 && n != 130) {
            abort();
        }
        break;
    case 4: { /* Modbus TCP: a read of 3 registers from unit 250 */
        const uint8_t req[] = {250, 0x03, 0x00, 0x1F, 0x00, 0x03};
        n = pymb_transact(tcp_line, req, sizeof req, 0, rsp, (int)sizeof rsp - 8, &fail);
        if (n >= 0 && (n != 8 || rsp[6] != 250 || rsp[2] != 0 || rsp[3] != 0 ||
                       ((rsp[0] << 8) | rsp[1]) != tcp_line->tid)) {
            abort();
        }
        break;
    }
    case 5: { /* RTU over TCP: any function code (0x41), ended by silence */
        const uint8_t req[] = {7, 0x41, 0x01};
        n = pymb_transact(rot_line, req, sizeof req, 0, rsp, (int)sizeof rsp - 8, &fail);
        if (n >= 0 && (rsp[0] != 7 || !pymb_rtu_crc_ok(rsp, (size_t)n + 3))) {
            abort();
        }
        break;
    }
    default: { /* a plan of three reads (pymb_read_plan), slave 249 */
        const pymb_plan_request plan[] = {
            {0x03, 249, 31, 125, 0}, {0x03, 249, 156, 125, 125}, {0x04, 249, 0, 8, 250}};
        size_t done = 99;
        int rc = pymb_read_plan(line, plan, 3, 0, regs, sizeof regs / sizeof regs[0], &done,
                                &fail);
        if ((rc == 0 && done != 3) || (rc == -1 && done > 2) || (rc != 0 && rc != -1)) {
            abort();
        }
        if (data[0] & 0x40) { /* the same plan held, decoding its last register */
            pymb_map_entry e;
            double value;
            uint8_t state;
            pymbi_map_job job;
            pymbi_plan held;

            memset(&e, 0, sizeof e);
            e.type = PYMB_MAP_U16;
            e.count = e.channels = 1;
            e.first = 257;
            pymb_map_order("AB", 2, e.order);
            memset(&job, 0, sizeof job);
            job.entries = &e;
            job.nentries = 1;
            job.regs = regs;
            job.nregs = sizeof regs / sizeof regs[0];
            job.out.values = &value;
            job.out.states = &state;
            job.out.len = 1;
            memset(&held, 0, sizeof held);
            held.reqs = plan;
            held.n = 3;
            held.regs = regs;
            held.nregs = sizeof regs / sizeof regs[0];
            held.then = &job;
            if (pymbi_map_ready(&job) != 1) {
                abort();
            }
            value = -1.0;
            rc = pymbi_plan_run(line, &held, 0, &fail);
            if ((rc == 0) != (held.decoded == 1) || held.done > 3 ||
                (rc == 0 && value != (double)regs[257])) {
                abort();
            }
        }
        break;
    }
    }
    resp.stop = 1;
    pthread_join(thread, NULL);
    if (fail.rsp_len < 0 || fail.rsp_len > (int)sizeof fail.rsp) {
        abort();
    }
    drain_master();
    return 0;
}
