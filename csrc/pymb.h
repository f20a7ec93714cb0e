/* SPDX-License-Identifier: MIT */
/*
 * pymb.h - pymb's C core: Modbus RTU CRC-16, frame checks and the sensor-block
 * decoders of the two devices pymb speaks to.
 *
 * This header and the files pymb_crc.c, pymb_frame.c and pymb_decode.c depend
 * on nothing but the C99 standard library: no Python, no libmodbus, no I/O.
 * The transport half (the register sweep over libmodbus) is in pymb_modbus.h.
 *
 * Conventions, after libmodbus: one `pymb_` prefix, the caller owns every
 * buffer and passes its length, nothing here keeps state between calls.
 * Errors: a function that can fail returns -1 and sets errno (EINVAL for a
 * bad argument, libmodbus's EMB* codes for protocol errors: the PYMB_EMB*
 * values below), and pymb_strerror() names them all. The frame checks return
 * a pymb_frame_status instead: their answer is the classification itself.
 * Each function's man page (section 3) says what it writes on failure.
 *
 * Documents cited:
 *   [MB-AP]  Modbus Application Protocol Specification V1.1b3
 *   [MB-SL]  Modbus over Serial Line Specification V1.02
 *   [CP]     CoolPro Modbus RTU Communications Protocol, CP-MODBUS-RTU rev 1
 *   [HUB]    RS485 Modbus Communication Protocol V1.5 (100-channel sensor hub)
 *   [NOTES]  docs/device-notes.md, the project's reading of [CP] and [HUB]
 */
#ifndef PYMB_H
#define PYMB_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The one home of pymb's version: the Makefile (SONAME, pymb.pc), setup.py
 * (the Python package's version) and pymb.__version__ all read it here. */
#define PYMB_VERSION_MAJOR 0
#define PYMB_VERSION_MINOR 1
#define PYMB_VERSION_PATCH 0

#define PYMB_STRINGIFY_(x) #x
#define PYMB_STRINGIFY(x) PYMB_STRINGIFY_(x)
#define PYMB_VERSION_STRING                                                      \
    PYMB_STRINGIFY(PYMB_VERSION_MAJOR) "." PYMB_STRINGIFY(PYMB_VERSION_MINOR) "." \
    PYMB_STRINGIFY(PYMB_VERSION_PATCH)
/* 0x000100 for 0.1.0: compares as the versions do. */
#define PYMB_VERSION_HEX \
    ((PYMB_VERSION_MAJOR << 16) | (PYMB_VERSION_MINOR << 8) | PYMB_VERSION_PATCH)
/* True when the headers are version major.minor.patch or later. */
#define PYMB_VERSION_CHECK(major, minor, patch) \
    (PYMB_VERSION_HEX >= (((major) << 16) | ((minor) << 8) | (patch)))

/* The version of the library linked at run time ("0.1.0"), which may differ
 * from the PYMB_VERSION_STRING a program was compiled with. */
const char *pymb_version(void);

/* ------------------------------------------------------------------------ */
/* Errors: errno values, as libmodbus numbers them (modbus.h: MODBUS_ENOBASE
 * + the exception code, then its own protocol errors), so that errno means
 * the same with or without libmodbus; pymb_line.c checks that they agree. */
#define PYMB_ENOBASE 112345678
#define PYMB_EMBXILFUN (PYMB_ENOBASE + 1)   /* exception 01: illegal function */
#define PYMB_EMBXILADD (PYMB_ENOBASE + 2)   /* 02: illegal data address */
#define PYMB_EMBXILVAL (PYMB_ENOBASE + 3)   /* 03: illegal data value */
#define PYMB_EMBXSFAIL (PYMB_ENOBASE + 4)   /* 04: server device failure */
#define PYMB_EMBXACK (PYMB_ENOBASE + 5)     /* 05: acknowledge */
#define PYMB_EMBXSBUSY (PYMB_ENOBASE + 6)   /* 06: server device busy */
#define PYMB_EMBXNACK (PYMB_ENOBASE + 7)    /* 07: negative acknowledge */
#define PYMB_EMBXMEMPAR (PYMB_ENOBASE + 8)  /* 08: memory parity error */
#define PYMB_EMBXGPATH (PYMB_ENOBASE + 10)  /* 0A: gateway path unavailable */
#define PYMB_EMBXGTAR (PYMB_ENOBASE + 11)   /* 0B: gateway target failed */
#define PYMB_EMBBADCRC (PYMB_ENOBASE + 12)  /* bad CRC */
#define PYMB_EMBBADDATA (PYMB_ENOBASE + 13) /* reply not as asked */
#define PYMB_EMBBADEXC (PYMB_ENOBASE + 14)  /* exception code above 0x0B */
#define PYMB_EMBUNKEXC (PYMB_ENOBASE + 15)  /* unknown exception */
#define PYMB_EMBMDATA (PYMB_ENOBASE + 16)   /* too many data */
#define PYMB_EMBBADSLAVE (PYMB_ENOBASE + 17) /* reply from another address */
/* Exception codes 0x0C..0xFF ([MB-AP] 7 allows 1..255 on the wire) fail a
 * request with PYMB_EXCEPTION_ENOBASE + code: libmodbus uses PYMB_ENOBASE +
 * 12..17 for its own errors, so those codes need a range of their own. */
#define PYMB_EXCEPTION_ENOBASE (PYMB_ENOBASE + 0x100)

/* A description of errnum: one of the codes above (the exceptions named as
 * [MB-AP] 7 names them), or strerror()'s text for
 * the OS's errno values. Never NULL; the text is static and must not be
 * modified. */
const char *pymb_strerror(int errnum);

/* [MB-SL] 2.5.1.1: an RTU frame is at most 256 bytes (address, PDU, CRC). */
#define PYMB_RTU_MAX_ADU 256
/* [MB-AP] 4.1: the PDU is at most 253 bytes. */
#define PYMB_MAX_PDU 253
/* [MB-AP] 6.3 / 6.4: 1 to 125 registers per read (0x7D). */
#define PYMB_MAX_READ_REGISTERS 125
/* [MB-AP] 6.1 / 6.2: 1 to 2000 bits per read (0x7D0). */
#define PYMB_MAX_READ_BITS 2000
/* [HUB] 2.1: no frame longer than 255 bytes; 5 + 2 * 125 = 255, so the
 * 125-register limit of [MB-AP] is also the hub's. */
#define PYMB_HUB_MAX_FRAME 255

/* ------------------------------------------------------------------------ */
/* CRC-16/MODBUS: polynomial 0xA001 (reflected 0x8005), initial 0xFFFF,
 * transmitted low byte first ([MB-SL] 6.2.2, [CP] ch. 04). Table-driven,
 * one 16-bit table lookup per byte.                                         */

/* CRC of `len` bytes. pymb_crc16("123456789", 9) == 0x4B37. */
uint16_t pymb_crc16(const uint8_t *data, size_t len);

/* Continue a CRC over more bytes; start with crc = 0xFFFF. */
uint16_t pymb_crc16_update(uint16_t crc, const uint8_t *data, size_t len);

/* 1 when the last two bytes of `frame` are the CRC of the bytes before them
 * (low byte first), 0 otherwise (also when len < 3); -1 (EINVAL) when frame
 * is NULL. */
int pymb_rtu_crc_ok(const uint8_t *frame, size_t len);

/* Append the CRC to frame[0..len). Returns the new length, or -1 (EINVAL)
 * when len + 2 > cap, len + 2 > PYMB_RTU_MAX_ADU or frame is NULL. */
int pymb_rtu_append_crc(uint8_t *frame, size_t len, size_t cap);

/* ------------------------------------------------------------------------ */
/* Frame checks, on PDUs (function code first) so that RTU and TCP share them. */

/* Results of the checks below; every error is negative. */
typedef enum {
    PYMB_FRAME_OK = 0,
    PYMB_FRAME_EXCEPTION = 1,     /* a well-formed exception response */
    PYMB_FRAME_INCOMPLETE = -1,   /* more bytes are needed */
    PYMB_FRAME_BAD_CRC = -2,
    PYMB_FRAME_BAD_SLAVE = -3,    /* answered by another address */
    PYMB_FRAME_BAD_FUNCTION = -4, /* function code not the one asked */
    PYMB_FRAME_BAD_LENGTH = -5,   /* byte count or length not as asked */
    PYMB_FRAME_BAD_ECHO = -6,     /* a write's echo differs from the request */
    PYMB_FRAME_TOO_LONG = -7,     /* longer than the frame limit */
    PYMB_FRAME_INVALID = -8,      /* a NULL pointer or an impossible request */
    PYMB_FRAME_BAD_HEADER = -9    /* [MB-TCP] MBAP protocol id not 0, or a length
                                   * that cannot be (not 2..254) */
} pymb_frame_status;

/* Short English description of a pymb_frame_status ("bad CRC", ...). */
const char *pymb_frame_strerror(pymb_frame_status status);

/* Total length of the RTU response frame whose first `have` bytes are in
 * `rsp` (address, function, ...; CRC included), as the function code and byte
 * count tell it. Returns PYMB_FRAME_INCOMPLETE when `have` is too short to
 * tell, PYMB_FRAME_TOO_LONG when the frame would exceed PYMB_RTU_MAX_ADU,
 * PYMB_FRAME_BAD_FUNCTION for a function code whose reply length this file
 * does not know (0x08, 0x2B, user-defined codes): only the line's silence
 * (or the caller's knowledge) ends such a frame. */
int pymb_rtu_response_length(const uint8_t *rsp, size_t have);

/* Total length of the RTU request frame whose first `have` bytes are in
 * `req`, for a server reading requests. PYMB_FRAME_INCOMPLETE when more bytes
 * are needed to tell, PYMB_FRAME_BAD_FUNCTION for a function code whose
 * length only the line's silence can tell, PYMB_FRAME_TOO_LONG past 256. */
int pymb_rtu_request_length(const uint8_t *req, size_t have);

/* Check a response PDU against the request PDU that asked for it: the
 * function code, the byte count for reads ([MB-AP] 6.1-6.4, 6.17), the echo
 * for single writes and mask write ([MB-AP] 6.5, 6.6, 6.16), address and
 * quantity for multiple writes ([MB-AP] 6.11, 6.12). Returns PYMB_FRAME_OK,
 * PYMB_FRAME_EXCEPTION (and the code in *exception_code when not NULL) or a
 * negative pymb_frame_status. */
int pymb_check_response_pdu(const uint8_t *req, size_t req_len, const uint8_t *rsp,
                            size_t rsp_len, int *exception_code);

/* The same for a whole RTU response frame (address + PDU + CRC) against the
 * request (address + PDU, *without* its CRC: the whole request matters, as
 * a write's echo is compared with it). The CRC is checked first, then the
 * address, then the PDU. */
int pymb_rtu_check_response(const uint8_t *req, size_t req_len, const uint8_t *rsp,
                            size_t rsp_len, int *exception_code);

/* ------------------------------------------------------------------------ */
/* Decoding primitives.                                                      */

/* What a decoded value is. Kept apart as [NOTES] asks: a value, the
 * channel's "offline" marker, the "no sensor of this kind" marker, a block
 * the device's firmware does not have; or not read this time. */
typedef enum {
    PYMB_VALUE = 0,
    PYMB_OFFLINE = 1,
    PYMB_NO_SENSOR = 2,
    PYMB_UNSUPPORTED = 3,
    PYMB_NOT_READ = 4 /* not asked for in this read */
} pymb_state;

/* Sign-magnitude tenths ([HUB] 3, temperatures): bit 15 is the sign, bits
 * 14..0 the magnitude in tenths. 0x8000 decodes as -0.0, not as a marker.
 * The caller checks 0xFFFF (offline) first. */
double pymb_sm_tenths(uint16_t raw);

/* Milliunits ([CP] ch. 04): raw / 1000. */
double pymb_milli(uint16_t raw);

/* A 32-bit value stored low word first, each word big-endian ([CP] ch. 04):
 * reads regs[0] (low) and regs[1] (high) into *value. Returns 0, or -1
 * (EINVAL, *value untouched) when regs or value is NULL: every uint32_t is a
 * valid value, so the status comes apart from it. */
int pymb_u32_lo_hi(const uint16_t *regs, uint32_t *value);

/* ------------------------------------------------------------------------ */
/* Sensor hub ([HUB] 3, [NOTES]): 7 blocks of 100 registers from 31 to 730.  */

#define PYMB_HUB_FIRST_REGISTER 31  /* [NOTES]: on-wire PDU address */
#define PYMB_HUB_CHANNELS 100
#define PYMB_HUB_BLOCKS 7
#define PYMB_HUB_REGISTERS (PYMB_HUB_CHANNELS * PYMB_HUB_BLOCKS) /* 700 */
#define PYMB_HUB_ALL_BLOCKS 0x7Fu

/* Blocks in address order; block b holds channel c (0-based) at register
 * PYMB_HUB_FIRST_REGISTER + 100 * b + c. */
typedef enum {
    PYMB_HUB_TEMPERATURE = 0,          /* 31..130, sign-magnitude 0.1 degC */
    PYMB_HUB_HUMIDITY = 1,             /* 131..230, 1 % or 0.1 % per channel */
    PYMB_HUB_PRESSURE_TEMPERATURE = 2, /* 231..330, sign-magnitude 0.1 degC */
    PYMB_HUB_PRESSURE = 3,             /* 331..430, kPa unsigned */
    PYMB_HUB_VOLTAGE = 4,              /* 431..530, mV unsigned, fw >= V2.19 */
    PYMB_HUB_RSSI = 5,                 /* 531..630, dBm int16, fw >= V2.19 */
    PYMB_HUB_TEMPERATURE2 = 6          /* 631..730, sign-magnitude, fw >= V2.23 */
} pymb_hub_block;

/* Markers ([HUB] 3). */
#define PYMB_HUB_OFFLINE 0xFFFFu
#define PYMB_HUB_NO_HUMIDITY_1PCT 0x00FFu   /* humidity in 1 % units */
#define PYMB_HUB_NO_HUMIDITY_TENTHS 0x8000u /* humidity in 0.1 % units */

/* Decode one raw hub register of `block` into *value and return its
 * pymb_state. `humidity_tenths` (humidity block only): nonzero when the
 * channel's sensor reports in 0.1 %, zero for 1 %. *value is NaN for every
 * state but PYMB_VALUE. Returns -1 (EINVAL, *value NaN) for an unknown block. */
int pymb_hub_decode_one(pymb_hub_block block, uint16_t raw, int humidity_tenths,
                        double *value);

/* Bitmaps over the 700 sweep registers: bit i (byte i / 8, bit i % 8) is
 * register PYMB_HUB_FIRST_REGISTER + i. */
#define PYMB_HUB_BITMAP_BYTES ((PYMB_HUB_REGISTERS + 7) / 8)

/* One read request: `count` registers from `address`. */
typedef struct {
    uint16_t address;
    uint16_t count;
} pymb_span;

typedef struct {
    int busy_retries;         /* re-sends after the hub's busy answer (exception
                               * 04, [HUB] 2.3.2.3) before giving up */
    uint32_t busy_backoff_us; /* wait before the first re-send; doubles each time */
} pymb_hub_options;

/* A hub read and its decoding: pymb_hub_read (pymb_modbus.h) fills regs and
 * read_mask and then decodes; pymb_hub_decode decodes registers that came
 * another way. The fields a function does not use are ignored by it. */
typedef struct {
    /* in (pymb_hub_read) */
    int slave;                       /* 1..255 */
    /* in (both) */
    unsigned channels;               /* 1..100: channels 1..channels are decoded */
    const uint8_t *humidity_tenths;  /* `channels` bytes, nonzero where that channel's
                                      * humidity is in 0.1 %; NULL: 0.1 % on every one */
    const uint8_t *wanted;           /* PYMB_HUB_BITMAP_BYTES: the registers asked for;
                                      * NULL: all of the spans (all 700 when decoding) */
    /* in (pymb_hub_read) */
    const pymb_span *spans;          /* the plan, inside 31..730 */
    int nspans;
    pymb_hub_options options;
    /* in and out: blocks known to be missing from the firmware; pymb_hub_read
     * adds the blocks it finds missing (exception 02 on a read of that block
     * alone). A block not read decodes as PYMB_UNSUPPORTED when its bit is
     * set here, as PYMB_NOT_READ otherwise. */
    unsigned unsupported;
    /* out (pymb_hub_read), in (pymb_hub_decode): bit b set when every
     * requested register of block b was read */
    unsigned read_mask;
    uint16_t *regs;                  /* PYMB_HUB_REGISTERS raw registers 31..730 in
                                      * address order (regs[100 * b + c]) */
    /* out: out_len >= 7 * channels entries each, block-major
     * (values[b * channels + c]); NaN wherever the state is not a value.
     * pymb_hub_read: values NULL means no decode. */
    double *values;
    uint8_t *states;
    size_t out_len;
} pymb_hub_request;

/* Decode rq->regs into rq->values and rq->states as rq->read_mask,
 * rq->unsupported, rq->wanted and rq->humidity_tenths say: registers not
 * wanted decode as PYMB_NOT_READ. Returns 0, or -1 (EINVAL) when rq, regs,
 * values or states is NULL, channels is not 1..100 or out_len is short:
 * nothing is written then. */
int pymb_hub_decode(const pymb_hub_request *rq);

/* ------------------------------------------------------------------------ */
/* CoolPro ([CP] ch. 03).                                                    */

/* Input registers 0..7 ([CP] "live telemetry"). */
#define PYMB_COOLPRO_TELEMETRY_ADDRESS 0
#define PYMB_COOLPRO_TELEMETRY_COUNT 8
/* Input registers 100..107 ([CP] "device information"). */
#define PYMB_COOLPRO_IDENTITY_ADDRESS 100
#define PYMB_COOLPRO_IDENTITY_COUNT 8

typedef struct {
    double input_voltage_v;
    double input_current_a;
    double output_voltage_v;
    double output_current_a;
    double temperature_c;
    uint32_t uptime_s;
    uint16_t status; /* bits 0..6 as [CP] lists them, 7..15 reserved, kept */
} pymb_coolpro_telemetry;

typedef struct {
    uint32_t serial_number;
    uint16_t hardware_revision;
    uint16_t firmware_major;
    uint16_t firmware_minor;
    uint16_t firmware_patch;
    uint32_t manufactured; /* Unix time, UTC */
} pymb_coolpro_identity;

/* Decode input registers 0..7 / 100..107. nregs must be 8. Return 0, or -1
 * (EINVAL; *out untouched) for a NULL pointer or another nregs. */
int pymb_coolpro_decode_telemetry(const uint16_t *regs, size_t nregs,
                                  pymb_coolpro_telemetry *out);
int pymb_coolpro_decode_identity(const uint16_t *regs, size_t nregs,
                                 pymb_coolpro_identity *out);

#ifdef __cplusplus
}
#endif

/* Device maps: the table-driven decoder. */
#include "pymb_map.h"

#endif /* PYMB_H */
