/* SPDX-License-Identifier: MIT */
/*
 * pymb_serve.h - the requests a Modbus TCP server takes from its clients
 * (pymb serve, pymb.serve), parsed and checked with no I/O. Not installed
 * and not in libpymb: the Python extension compiles pymb_serve.c beside the
 * core; names are pymbi_*.
 *
 * A client's bytes are taken one frame at a time (pymbi_srv_take): the MBAP
 * header is checked ([MB-TCP] 3.1.3: protocol id 0, a length of 2..254 that
 * holds the unit id and a PDU of at most 253 bytes) and the PDU is checked as
 * a server checks it before doing anything ([MB-APP] 6.1-6.19 and the
 * state diagrams of each function): its size for its function code, the
 * quantities in range, a byte count that agrees with the quantity. A well
 * formed request is forwarded; a badly formed one is answered with the
 * exception the specification names (01 illegal function, 03 illegal data
 * value, 02 illegal data address for a range that runs past 65535); bytes
 * that cannot be a Modbus TCP frame end the client's connection.
 *
 * Documents cited:
 *   [MB-TCP] Modbus Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3, 4.4.1
 *   [MB-APP] Modbus Application Protocol V1.1b3, 4.1 (PDU size), 6 (functions), 7 (exceptions)
 */
#ifndef PYMB_SERVE_H
#define PYMB_SERVE_H

#include <stddef.h>
#include <stdint.h>

#define PYMBI_SRV_MBAP 7        /* transaction id, protocol id, length, unit id */
#define PYMBI_SRV_MAX_PDU 253   /* [MB-APP] 4.1 */
#define PYMBI_SRV_MAX_FRAME 260 /* MBAP + the largest PDU */

/* What pymbi_srv_take found: the frame's fields and what to do with it. */
typedef struct {
    uint16_t tid;      /* the client's transaction id, to echo */
    uint8_t unit;      /* unit identifier */
    uint8_t function;  /* the PDU's function code */
    uint16_t pdu_len;  /* the PDU's bytes (function code + data), at offset PYMBI_SRV_MBAP */
    uint8_t exception; /* 0: well formed, forward it; else the exception code to answer */
} pymbi_srv_req;

/* Check a request PDU (function code and data, len bytes) as a server does.
 * Returns 0 when it is well formed (or of a function code this layer does not
 * know, 1..127, which only the device can judge), else the exception code to
 * answer: 1 (function code 0 or 128..255), 3 (size, quantity or byte count
 * out of range), 2 (address + quantity past 65536). */
int pymbi_srv_check_pdu(const uint8_t *pdu, size_t len);

/* Take the first frame of buf[0 .. len). Returns its length (> 0) and fills
 * *req; 0 when more bytes are needed; -1 when the bytes cannot be a Modbus
 * TCP request (protocol id other than 0, a length field under 2 or over 254):
 * the connection is to be closed. -1 with errno EINVAL on NULL arguments. */
int pymbi_srv_take(const uint8_t *buf, size_t len, pymbi_srv_req *req);

/* Write the reply frame to a request: MBAP with tid and unit, then the PDU
 * (pdu_len 1..253 bytes). Returns the frame's length, -1 (errno EINVAL) when
 * the PDU's size is out of range or out_cap is too small. */
int pymbi_srv_reply(uint16_t tid, uint8_t unit, const uint8_t *pdu, size_t pdu_len,
                    uint8_t *out, size_t out_cap);

/* Write the exception reply (function | 0x80, code) to a request. Returns 9,
 * or -1 (errno EINVAL) when out_cap is under 9 or code is 0. */
int pymbi_srv_exception(uint16_t tid, uint8_t unit, uint8_t function, uint8_t code,
                        uint8_t *out, size_t out_cap);

#endif
