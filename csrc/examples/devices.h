/* SPDX-License-Identifier: MIT */
/*
 * devices.h - the two devices of pymb's examples as small compiled-in maps
 * for libpymb's generic map decoder (pymb_map_decode), and their reads with
 * the generic request path (pymb_read_plan). libpymb itself knows no device:
 * this is what a C program writes for its own.
 *
 * Documents cited:
 *   [HUB]    RS485 Modbus Communication Protocol V1.5 (100-channel sensor hub)
 *   [CP]     CoolPro Modbus RTU Communications Protocol, CP-MODBUS-RTU rev 1
 *   [NOTES]  docs/device-notes.md, the project's reading of [CP] and [HUB]
 *
 * A header of static inline functions: each program keeps the ones it uses.
 */
#ifndef PYMB_EXAMPLE_DEVICES_H
#define PYMB_EXAMPLE_DEVICES_H

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "pymb_modbus.h"

/* ---- the line -------------------------------------------------------------- */

/* Open PORT: a serial device at `baud` (RTU, 8N1), or "tcp:HOST:PORT" (Modbus
 * TCP; baud unused), with a reply timeout of timeout_ms. Returns the line
 * (its context in *ctx), or NULL with the reason on stderr. */
static inline pymb_line *example_open(const char *port, int baud, int timeout_ms,
                                      modbus_t **ctx)
{
    pymb_line *line;
    int tcp = strncmp(port, "tcp:", 4) == 0;

    if (tcp) {
        char host[256];
        const char *colon = strrchr(port + 4, ':');
        size_t len = colon ? (size_t)(colon - (port + 4)) : 0;
        if (colon == NULL || len == 0 || len >= sizeof host) {
            fprintf(stderr, "%s: not tcp:HOST:PORT\n", port);
            return NULL;
        }
        memcpy(host, port + 4, len);
        host[len] = '\0';
        *ctx = modbus_new_tcp_pi(host, colon + 1);
    } else {
        *ctx = modbus_new_rtu(port, baud, 'N', 8, 1);
    }
    if (*ctx == NULL || modbus_connect(*ctx) == -1) {
        fprintf(stderr, "cannot open %s: %s\n", port, pymb_strerror(errno));
        modbus_free(*ctx);
        return NULL;
    }
    modbus_set_response_timeout(*ctx, (uint32_t)(timeout_ms / 1000),
                                (uint32_t)(timeout_ms % 1000) * 1000u);
    modbus_set_byte_timeout(*ctx, 0, 0);
    line = pymb_line_new(*ctx, tcp ? PYMB_FRAMING_TCP : PYMB_FRAMING_RTU,
                         tcp ? 0 : pymb_rtu_silence_us(baud));
    if (line == NULL) {
        fprintf(stderr, "cannot set up %s: %s\n", port, pymb_strerror(errno));
        modbus_close(*ctx);
        modbus_free(*ctx);
    }
    return line;
}

static inline void example_close(pymb_line *line, modbus_t *ctx)
{
    pymb_line_free(line);
    modbus_close(ctx);
    modbus_free(ctx);
}

/* ---- the sensor hub ([HUB] 3, [NOTES]) ---------------------------------- */

/* 7 blocks of 100 holding registers, 31..730: block b holds channel c
 * (0-based) at 31 + 100 * b + c. */
#define HUB_FIRST 31
#define HUB_CHANNELS 100
#define HUB_BLOCKS 7
#define HUB_REGISTERS (HUB_CHANNELS * HUB_BLOCKS)

static const char *const hub_block_names[HUB_BLOCKS] = {
    "temperature_c", "humidity_pct", "pressure_temperature_c", "pressure_kpa",
    "voltage_mv",    "rssi_dbm",     "temperature2_c",
};

/* [HUB] 3: 0xFFFF is "offline" in every block; humidity in 0.1 % (the
 * hub's default unit, [NOTES]) says "no humidity sensor" with 0x8000. */
static const pymb_map_marker hub_markers[] = {
    {0xFFFFu, PYMB_OFFLINE},
    {0xFFFFu, PYMB_OFFLINE}, {0x8000u, PYMB_NO_SENSOR},
};

#define HUB_BLOCK(b, kind, tenths, marker, nmarker)                                         \
    {.first = (b) * HUB_CHANNELS, .out = (b) * HUB_CHANNELS, .channels = HUB_CHANNELS,     \
     .stride = 1, .count = 1, .first_marker = (marker), .nmarkers = (nmarker),            \
     .type = (kind), .flags = (tenths) ? PYMB_MAP_SCALED : 0u, .decimals = (tenths),       \
     .order = {0, 1}, .scale = (tenths) ? 0.1 : 1.0}

/* Temperatures: sign-magnitude tenths of a degree; humidity: tenths of a
 * percent; pressure (kPa) and voltage (mV) unsigned; RSSI two's complement. */
static const pymb_map_entry hub_entries[HUB_BLOCKS] = {
    HUB_BLOCK(0, PYMB_MAP_SM16, 1, 0, 1), HUB_BLOCK(1, PYMB_MAP_U16, 1, 1, 2),
    HUB_BLOCK(2, PYMB_MAP_SM16, 1, 0, 1), HUB_BLOCK(3, PYMB_MAP_U16, 0, 0, 1),
    HUB_BLOCK(4, PYMB_MAP_U16, 0, 0, 1),  HUB_BLOCK(5, PYMB_MAP_I16, 0, 0, 1),
    HUB_BLOCK(6, PYMB_MAP_SM16, 1, 0, 1),
};

/* The fewest reads of every block not in `missing` (bit b: block b): whole
 * blocks are contiguous, so runs of them merge, at most 125 registers a
 * request. Returns the number of requests written to plan[0..cap). */
static inline size_t hub_plan(int slave, unsigned missing, pymb_plan_request *plan,
                              size_t cap)
{
    size_t n = 0;
    unsigned b = 0;

    while (b < HUB_BLOCKS) {
        unsigned start, end;
        if (missing & (1u << b)) {
            b++;
            continue;
        }
        start = b * HUB_CHANNELS;
        for (end = start; b < HUB_BLOCKS && !(missing & (1u << b)); b++) {
            end += HUB_CHANNELS;
        }
        for (; start < end && n < cap; n++) {
            unsigned count = end - start > PYMB_MAX_READ_REGISTERS ? PYMB_MAX_READ_REGISTERS
                                                                   : end - start;
            plan[n].function = MODBUS_FC_READ_HOLDING_REGISTERS;
            plan[n].slave = (uint8_t)slave;
            plan[n].address = (uint16_t)(HUB_FIRST + start);
            plan[n].count = (uint16_t)count;
            plan[n].offset = start;
            start += count;
        }
    }
    return n;
}

/* Read registers 31..730 into regs[HUB_REGISTERS]: the plan in one call;
 * a request refused with exception 02 (a block the firmware lacks, [NOTES])
 * is read again block by block, and a block refused on its own is added to
 * *missing. Returns 0, or -1 and errno as pymb_read_plan. */
static inline int hub_read(pymb_line *line, int slave, uint16_t *regs, unsigned *missing,
                    pymb_failure *fail)
{
    pymb_plan_request plan[16];
    size_t n = hub_plan(slave, *missing, plan, 16), from = 0, done;

    while (from < n) {
        unsigned b;
        const pymb_plan_request *rq;

        /* a request inside blocks found missing is not sent again */
        if ((*missing >> (plan[from].offset / HUB_CHANNELS)) & 1u &&
            (*missing >> ((plan[from].offset + plan[from].count - 1u) / HUB_CHANNELS)) & 1u) {
            from++;
            continue;
        }
        if (pymb_read_plan(line, plan + from, n - from, 0, regs, HUB_REGISTERS, &done,
                           fail) == 0) {
            return 0;
        }
        if (errno != PYMB_EMBXILADD) {
            return -1;
        }
        rq = &plan[from + done];
        for (b = rq->offset / HUB_CHANNELS; b < HUB_BLOCKS; b++) {
            unsigned lo = b * HUB_CHANNELS, hi = lo + HUB_CHANNELS;
            unsigned end = rq->offset + rq->count;
            if (lo >= end) {
                break;
            }
            if (*missing & (1u << b)) {
                continue;
            }
            lo = lo < rq->offset ? rq->offset : lo;
            hi = hi > end ? end : hi;
            if (pymb_read_registers(line, MODBUS_FC_READ_HOLDING_REGISTERS, slave,
                                    (int)(HUB_FIRST + lo), (int)(hi - lo), regs + lo,
                                    fail) < 0) {
                if (errno != PYMB_EMBXILADD) {
                    return -1;
                }
                *missing |= 1u << b;
            }
        }
        from += done + 1;
    }
    return 0;
}

/* Decode regs[HUB_REGISTERS] into values and states (HUB_REGISTERS each,
 * block-major); the blocks in `missing` as PYMB_UNSUPPORTED. Returns 0 or -1. */
static inline int hub_decode(const uint16_t *regs, unsigned missing, double *values,
                             uint8_t *states)
{
    pymb_map_out out;
    unsigned b, c;

    memset(&out, 0, sizeof out);
    out.values = values;
    out.states = states;
    out.len = HUB_REGISTERS;
    if (pymb_map_decode(hub_entries, HUB_BLOCKS, hub_markers,
                        sizeof hub_markers / sizeof hub_markers[0], regs, HUB_REGISTERS,
                        &out) < 0) {
        return -1;
    }
    for (b = 0; b < HUB_BLOCKS; b++) {
        for (c = 0; missing & (1u << b) && c < HUB_CHANNELS; c++) {
            values[b * HUB_CHANNELS + c] = NAN;
            states[b * HUB_CHANNELS + c] = PYMB_UNSUPPORTED;
        }
    }
    return 0;
}

/* ---- the CoolPro power supply ([CP] ch. 03, 04) -------------------------- */

/* Input registers 0..7 (telemetry) and 100..107 (identity), read into one
 * buffer of 16: telemetry at 0..7, identity at 8..15. */
#define CP_REGISTERS 16
#define CP_VALUES 13

static const char *const coolpro_names[CP_VALUES] = {
    "input_voltage_v", "input_current_a", "output_voltage_v", "output_current_a",
    "temperature_c",   "uptime_s",        "status",           "serial_number",
    "hardware_revision", "firmware_major", "firmware_minor",  "firmware_patch",
    "manufactured",
};

#define CP_MILLI(i) \
    {.first = (i), .out = (i), .channels = 1, .count = 1, .type = PYMB_MAP_U16, \
     .flags = PYMB_MAP_SCALED, .decimals = 3, .order = {0, 1}, .scale = 0.001}
#define CP_U16(reg, slot) \
    {.first = (reg), .out = (slot), .channels = 1, .count = 1, .type = PYMB_MAP_U16, \
     .order = {0, 1}, .scale = 1.0}
/* [CP] ch. 04: 32-bit values low word first, each word big-endian: CDAB. */
#define CP_U32_LOW_FIRST(reg, slot) \
    {.first = (reg), .out = (slot), .channels = 1, .count = 2, .type = PYMB_MAP_U32, \
     .order = {2, 3, 0, 1}, .scale = 1.0}

static const pymb_map_entry coolpro_entries[CP_VALUES] = {
    CP_MILLI(0), CP_MILLI(1), CP_MILLI(2), CP_MILLI(3), CP_MILLI(4),
    CP_U32_LOW_FIRST(5, 5), CP_U16(7, 6),
    CP_U32_LOW_FIRST(8, 7), CP_U16(10, 8), CP_U16(11, 9), CP_U16(12, 10), CP_U16(13, 11),
    CP_U32_LOW_FIRST(14, 12),
};

/* Both reads in one pymb_read_plan call, then the decode: values (floats)
 * and ints (the exact integers) of CP_VALUES slots. Returns 0, or -1 and
 * errno (EINVAL for a decode that cannot be, which this table is not). */
static inline int coolpro_read(pymb_line *line, int slave, double *values, int64_t *ints,
                        pymb_failure *fail)
{
    const pymb_plan_request plan[2] = {
        {MODBUS_FC_READ_INPUT_REGISTERS, (uint8_t)slave, 0, 8, 0},
        {MODBUS_FC_READ_INPUT_REGISTERS, (uint8_t)slave, 100, 8, 8},
    };
    uint16_t regs[CP_REGISTERS] = {0};
    uint8_t states[CP_VALUES];
    pymb_map_out out;

    if (pymb_read_plan(line, plan, 2, 0, regs, CP_REGISTERS, NULL, fail) < 0) {
        return -1;
    }
    memset(&out, 0, sizeof out);
    out.values = values;
    out.ints = ints;
    out.states = states;
    out.len = CP_VALUES;
    return pymb_map_decode(coolpro_entries, CP_VALUES, NULL, 0, regs, CP_REGISTERS, &out) < 0
               ? -1
               : 0;
}

#endif /* PYMB_EXAMPLE_DEVICES_H */
