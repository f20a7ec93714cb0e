/* SPDX-License-Identifier: MIT */
/*
 * pymb.h - pymb's C core: Modbus RTU CRC-16, frame checks and the
 * table-driven decoder of device maps (pymb_map.h).
 *
 * This header and the files pymb_crc.c, pymb_frame.c, pymb_error.c and
 * pymb_map.c depend on nothing but the C99 standard library: no Python, no
 * libmodbus, no I/O. The request path over libmodbus is in pymb_modbus.h.
 * Nothing here knows a particular device: a device is a map
 * (csrc/examples/ shows two, read through the generic API).
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
 *   [MB-TCP] Modbus Messaging on TCP/IP Implementation Guide V1.0b
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
#define PYMB_VERSION_MAJOR 1
#define PYMB_VERSION_MINOR 0
#define PYMB_VERSION_PATCH 0

#define PYMB_STRINGIFY_(x) #x
#define PYMB_STRINGIFY(x) PYMB_STRINGIFY_(x)
#define PYMB_VERSION_STRING                                                      \
    PYMB_STRINGIFY(PYMB_VERSION_MAJOR) "." PYMB_STRINGIFY(PYMB_VERSION_MINOR) "." \
    PYMB_STRINGIFY(PYMB_VERSION_PATCH)
/* 0x010000 for 1.0.0: compares as the versions do. */
#define PYMB_VERSION_HEX \
    ((PYMB_VERSION_MAJOR << 16) | (PYMB_VERSION_MINOR << 8) | PYMB_VERSION_PATCH)
/* True when the headers are version major.minor.patch or later. */
#define PYMB_VERSION_CHECK(major, minor, patch) \
    (PYMB_VERSION_HEX >= (((major) << 16) | ((minor) << 8) | (patch)))

/* The version of the library linked at run time ("1.0.0"), which may differ
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

/* ------------------------------------------------------------------------ */
/* CRC-16/MODBUS: polynomial 0xA001 (reflected 0x8005), initial 0xFFFF,
 * transmitted low byte first ([MB-SL] 6.2.2). Table-driven,
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
    PYMB_FRAME_BAD_HEADER = -9,   /* [MB-TCP] MBAP protocol id not 0, or a length
                                   * that cannot be (not 2..254) */
    PYMB_FRAME_BAD_TEXT = -10,    /* [MB-SL] 2.5.2 ASCII: a character that is no
                                   * hexadecimal digit, an odd digit count, or CR
                                   * not followed by LF */
    PYMB_FRAME_BAD_TID = -11      /* [MB-TCP] a reply to another transaction id:
                                   * dropped, and the wait went on */
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
/* Decoded values (pymb_map.h).                                             */

/* What a decoded value is: a value, a marker meaning "offline", one meaning
 * "no sensor of this kind", a block the device's firmware does not have; or
 * not read this time. A map's own markers add states (pymb_map.h). */
typedef enum {
    PYMB_VALUE = 0,
    PYMB_OFFLINE = 1,
    PYMB_NO_SENSOR = 2,
    PYMB_UNSUPPORTED = 3,
    PYMB_NOT_READ = 4 /* not asked for in this read */
} pymb_state;

#ifdef __cplusplus
}
#endif

/* Device maps: the table-driven decoder. */
#include "pymb_map.h"

#endif /* PYMB_H */
