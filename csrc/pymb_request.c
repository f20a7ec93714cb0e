/* SPDX-License-Identifier: MIT */
/*
 * pymb_request.c - the request path (see pymb_modbus.h): one request and its
 * checked reply, and the reads built on it. Everything that depends on the
 * transport goes through the line's transport table (pymb_internal.h).
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <string.h>
#include <time.h>

#include "pymb_internal.h"

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
    line->tr->flush_output(line);
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

int pymb_transact(pymb_line *line, const uint8_t *req, int req_len, int expect,
                  uint8_t *rsp, int rsp_cap, pymb_failure *fail)
{
    uint8_t adu[PYMB_ASCII_MAX_TEXT]; /* the longest: ASCII's characters */
    const pymb_transport *tr;
    int n, status, pdu_len, exc = 0, adu_len;
    uint64_t sent_us;

    pymb_failure_reset(fail);
    if (!pymbi_line_ok(line) || req == NULL || rsp == NULL || req_len < 2 ||
        req_len > PYMB_MAX_PDU + 1 || rsp_cap < MODBUS_MAX_ADU_LENGTH || expect < 0 ||
        expect > PYMB_MAX_PDU) {
        errno = EINVAL;
        return -1;
    }
    tr = line->tr;
    note_request(fail, req, req_len, tr->header_length);
    if (tr->prepare(line, req[0]) < 0) {
        return -1;
    }
    adu_len = tr->build(line, req, req_len, adu, (int)sizeof adu);
    sent_us = pymbi_now_us();
    if (adu_len < 0 || tr->send(line, adu, adu_len) < 0) {
        pymbi_owe(line, req[0]);
        return -1;
    }
    if (tr->broadcast && req[0] == MODBUS_BROADCAST_ADDRESS) {
        broadcast_wait(line);
        return 0;
    }
    n = tr->receive(line, req, req_len, expect, sent_us, rsp, rsp_cap, fail);
    if (n < 0) {
        return -1;
    }
    status = tr->check(line, req, req_len, rsp, n, expect, &exc);
    pdu_len = n - tr->header_length - tr->trailer_length;
    if (status == PYMB_FRAME_OK && expect > 0 && pdu_len != expect) {
        status = PYMB_FRAME_BAD_LENGTH;
    }
    if (status == PYMB_FRAME_OK) {
        return pdu_len;
    }
    pymbi_note_reply(fail, rsp, n, status);
    if (status == PYMB_FRAME_EXCEPTION) {
        /* A well-formed answer: the line is in step, nothing to recover. */
        errno = pymb_exception_errno(exc);
        return -1;
    }
    if (tr->lost_step(line)) {
        pymbi_owe(line, req[0]);
    }
    errno = frame_errno(status);
    return -1;
}

static int check_read_args(pymb_line *line, int slave, int addr, int nb, const void *dest)
{
    /* A read needs a reply: no broadcast. */
    if (line == NULL || dest == NULL || slave < line->tr->lowest_slave || slave > 255 ||
        addr < 0 || addr > 65535 || nb < 1 || nb > 65536 - addr) {
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
    return rsp + line->tr->header_length + 2; /* function code, byte count */
}

/* n registers from a reply's data (big-endian) into dest. n is a parameter,
 * not read through a pointer in the loop: a store into dest (uint16_t) could
 * change a uint16_t count in memory, so the compiler would read it again for
 * every register. On a little-endian host eight registers at a time: each
 * four loaded as one word, the two bytes of each register swapped by a mask
 * and two shifts, stored as one (memcpy: no alignment or aliasing
 * assumed); the rest, and every register on a big-endian host, one by one.
 * About 2 instructions a register (gcc -O2, x86-64). */
static void put_registers(uint16_t *dest, const uint8_t *data, int n)
{
    static const uint16_t probe = 1;
    const int little = *(const uint8_t *)&probe == 1; /* a constant to the compiler */
    int i = 0;

    if (little) {
        const uint64_t low = UINT64_C(0x00FF00FF00FF00FF);
        for (; i + 8 <= n; i += 8) {
            uint64_t w[2];
            memcpy(w, data + 2 * i, sizeof w);
            w[0] = (w[0] >> 8 & low) | (w[0] & low) << 8;
            w[1] = (w[1] >> 8 & low) | (w[1] & low) << 8;
            memcpy(dest + i, w, sizeof w);
        }
    }
    for (; i < n; i++) {
        dest[i] = (uint16_t)((unsigned)data[2 * i] << 8 | data[2 * i + 1]);
    }
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
        int n = nb - done > PYMB_MAX_READ_REGISTERS ? PYMB_MAX_READ_REGISTERS : nb - done;
        const uint8_t *data = read_request(line, function, slave, addr + done, n, rsp, fail);

        if (data == NULL) {
            return -1;
        }
        put_registers(dest + done, data, n);
        done += n;
    }
    return nb;
}

static void pause_plan_us(uint32_t us)
{
    struct timespec ts;
    ts.tv_sec = (time_t)(us / 1000000u);
    ts.tv_nsec = (long)(us % 1000000u) * 1000L;
    while (nanosleep(&ts, &ts) == -1 && errno == EINTR) {
    }
}

int pymb_read_plan(pymb_line *line, const pymb_plan_request *reqs, size_t n, uint32_t gap_us,
                   uint16_t *regs, size_t nregs, size_t *done, pymb_failure *fail)
{
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    size_t k;

    pymb_failure_reset(fail);
    if (done != NULL) {
        *done = 0;
    }
    if (line == NULL || (n > 0 && (reqs == NULL || regs == NULL))) {
        errno = EINVAL;
        return -1;
    }
    for (k = 0; k < n; k++) {
        const pymb_plan_request *rq = &reqs[k];
        if ((rq->function != MODBUS_FC_READ_HOLDING_REGISTERS &&
             rq->function != MODBUS_FC_READ_INPUT_REGISTERS) ||
            rq->count < 1 || rq->count > PYMB_MAX_READ_REGISTERS ||
            check_read_args(line, rq->slave, rq->address, rq->count, regs) < 0 ||
            rq->offset > nregs || rq->count > nregs - rq->offset) {
            errno = EINVAL;
            return -1;
        }
    }
    for (k = 0; k < n; k++) {
        const pymb_plan_request *rq = &reqs[k];
        const uint8_t *data;

        if (k > 0 && gap_us > 0) {
            pause_plan_us(gap_us);
        }
        data = read_request(line, rq->function, rq->slave, rq->address, rq->count, rsp, fail);
        if (data == NULL) {
            return -1;
        }
        put_registers(regs + rq->offset, data, rq->count);
        if (done != NULL) {
            *done = k + 1;
        }
    }
    return 0;
}

int pymbi_plan_run(pymb_line *line, pymbi_plan *plan, size_t start, pymb_failure *fail)
{
    int rc;

    if (plan == NULL || start > plan->n) {
        pymb_failure_reset(fail);
        if (plan != NULL) {
            plan->done = 0;
            plan->decoded = 0;
        }
        errno = EINVAL;
        return -1;
    }
    plan->decoded = 0;
    rc = pymb_read_plan(line, plan->reqs != NULL ? plan->reqs + start : NULL, plan->n - start,
                        plan->gap_us, plan->regs, plan->nregs, &plan->done, fail);
    if (rc == 0 && plan->then != NULL && pymbi_map_run(plan->then) >= 0) {
        plan->decoded = 1;
    }
    return rc;
}

int pymbi_plan_go(pymbi_plan *plan)
{
    if (plan == NULL) {
        errno = EINVAL;
        return -1;
    }
    return pymbi_plan_run(plan->line, plan, 0, plan->fail);
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
        int n = nb - done > PYMB_MAX_READ_BITS ? PYMB_MAX_READ_BITS : nb - done;
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
