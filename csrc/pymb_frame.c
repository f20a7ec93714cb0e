/* SPDX-License-Identifier: MIT */
/*
 * pymb_frame.c - Modbus frame lengths and response checks, with no I/O.
 *
 * Used by the request path (pymb_request.c frames every request and checks
 * every reply itself, for every address 0..255), by the sans-I/O TCP master
 * (pymb_master.c, which shares the MBAP framing, pymbi_mbap_frame, the MBAP
 * length rule, pymbi_mbap_length, and the TCP reply check, pymbi_tcp_check,
 * with the request path's TCP and UDP transports), by the device simulators, and by the fuzz targets. Everything reads only inside the lengths it is given.
 */
#include <string.h>

#include "pymb.h"
#include "pymb_master.h"

const char *pymb_frame_strerror(pymb_frame_status status)
{
    switch (status) {
    case PYMB_FRAME_OK:
        return "ok";
    case PYMB_FRAME_EXCEPTION:
        return "exception response";
    case PYMB_FRAME_INCOMPLETE:
        return "incomplete frame";
    case PYMB_FRAME_BAD_CRC:
        return "bad CRC";
    case PYMB_FRAME_BAD_SLAVE:
        return "reply from another address";
    case PYMB_FRAME_BAD_FUNCTION:
        return "reply to another function code";
    case PYMB_FRAME_BAD_LENGTH:
        return "reply length or byte count does not match the request";
    case PYMB_FRAME_BAD_ECHO:
        return "write echo does not match the request";
    case PYMB_FRAME_TOO_LONG:
        return "frame longer than 256 bytes";
    case PYMB_FRAME_INVALID:
        return "invalid argument";
    case PYMB_FRAME_BAD_HEADER:
        return "MBAP header with a protocol id other than 0 or an impossible length";
    case PYMB_FRAME_BAD_TEXT:
        return "ASCII frame with a character that is not a hexadecimal digit, an odd digit "
               "count or CR without LF";
    case PYMB_FRAME_BAD_TID:
        return "reply to another transaction id";
    default:
        return "unknown frame status";
    }
}

int pymb_rtu_response_length(const uint8_t *rsp, size_t have)
{
    int len;

    if (rsp == NULL || have < 2) {
        return PYMB_FRAME_INCOMPLETE;
    }
    if (rsp[1] & 0x80u) {
        return 5; /* address, function | 0x80, exception code, CRC */
    }
    switch (rsp[1]) {
    case 0x01: /* read coils */
    case 0x02: /* read discrete inputs */
    case 0x03: /* read holding registers */
    case 0x04: /* read input registers */
    case 0x11: /* report server id */
    case 0x17: /* read/write multiple registers */
        if (have < 3) {
            return PYMB_FRAME_INCOMPLETE;
        }
        len = 3 + rsp[2] + 2;
        break;
    case 0x05: /* write single coil: echo */
    case 0x06: /* write single register: echo */
    case 0x0F: /* write multiple coils: address, quantity */
    case 0x10: /* write multiple registers: address, quantity */
        len = 8;
        break;
    case 0x16: /* mask write register: echo */
        len = 10;
        break;
    case 0x07: /* read exception status: one byte */
        len = 5;
        break;
    default:
        return PYMB_FRAME_BAD_FUNCTION; /* unknown: only silence ends it */
    }
    return len > PYMB_RTU_MAX_ADU ? PYMB_FRAME_TOO_LONG : len;
}

int pymb_rtu_request_length(const uint8_t *req, size_t have)
{
    int len;

    if (req == NULL || have < 2) {
        return PYMB_FRAME_INCOMPLETE;
    }
    switch (req[1]) {
    case 0x01:
    case 0x02:
    case 0x03:
    case 0x04:
    case 0x05:
    case 0x06:
        return 8; /* address, function, 2 x 2 bytes, CRC */
    case 0x07:
    case 0x11:
        return 4; /* address, function, CRC */
    case 0x0F:
    case 0x10:
        if (have < 7) {
            return PYMB_FRAME_INCOMPLETE;
        }
        len = 7 + req[6] + 2;
        break;
    case 0x16:
        return 10;
    case 0x17:
        if (have < 11) {
            return PYMB_FRAME_INCOMPLETE;
        }
        len = 11 + req[10] + 2;
        break;
    default:
        return PYMB_FRAME_BAD_FUNCTION; /* unknown: only silence ends it */
    }
    return len > PYMB_RTU_MAX_ADU ? PYMB_FRAME_TOO_LONG : len;
}

int pymbi_mbap_length(const uint8_t *adu, size_t have)
{
    unsigned length;

    if (adu == NULL || have < 4) {
        return PYMB_FRAME_INCOMPLETE;
    }
    if (adu[2] != 0 || adu[3] != 0) {
        return PYMB_FRAME_BAD_HEADER;
    }
    if (have < 6) {
        return PYMB_FRAME_INCOMPLETE;
    }
    length = (unsigned)adu[4] << 8 | adu[5];
    if (length < 2 || length > 1 + PYMB_MAX_PDU) {
        return PYMB_FRAME_BAD_HEADER;
    }
    return 6 + (int)length;
}

int pymbi_mbap_frame(uint16_t tid, uint8_t unit, const uint8_t *pdu, size_t pdu_len,
                     uint8_t *adu)
{
    memmove(adu + 7, pdu, pdu_len);
    adu[0] = (uint8_t)(tid >> 8);
    adu[1] = (uint8_t)tid;
    adu[2] = 0;
    adu[3] = 0;
    adu[4] = (uint8_t)((pdu_len + 1) >> 8);
    adu[5] = (uint8_t)(pdu_len + 1);
    adu[6] = unit;
    return (int)pdu_len + 7;
}

int pymbi_tcp_check(uint8_t unit, const uint8_t *req_pdu, size_t req_len, const uint8_t *adu,
                    size_t n, int *exception_code)
{
    if (req_pdu == NULL || adu == NULL) {
        return PYMB_FRAME_INVALID;
    }
    if (n < 7) {
        return PYMB_FRAME_BAD_LENGTH;
    }
    if (adu[6] != unit) {
        return PYMB_FRAME_BAD_SLAVE;
    }
    return pymb_check_response_pdu(req_pdu, req_len, adu + 7, n - 7, exception_code);
}

static unsigned be16(const uint8_t *p)
{
    return ((unsigned)p[0] << 8) | p[1];
}

int pymb_check_response_pdu(const uint8_t *req, size_t req_len, const uint8_t *rsp,
                            size_t rsp_len, int *exception_code)
{
    unsigned fc;
    unsigned nb;

    if (req == NULL || rsp == NULL || req_len < 1) {
        return PYMB_FRAME_INVALID;
    }
    if (rsp_len < 1) {
        return PYMB_FRAME_BAD_LENGTH;
    }
    fc = req[0];
    if (rsp[0] == (fc | 0x80u) && !(fc & 0x80u)) {
        if (rsp_len != 2) {
            return PYMB_FRAME_BAD_LENGTH;
        }
        if (exception_code != NULL) {
            *exception_code = rsp[1];
        }
        return PYMB_FRAME_EXCEPTION;
    }
    if (rsp[0] != fc) {
        return PYMB_FRAME_BAD_FUNCTION;
    }
    switch (fc) {
    case 0x01:
    case 0x02:
        if (req_len < 5 || rsp_len < 2) {
            return req_len < 5 ? PYMB_FRAME_INVALID : PYMB_FRAME_BAD_LENGTH;
        }
        nb = be16(req + 3);
        if (rsp[1] != (nb + 7) / 8 || rsp_len != 2u + rsp[1]) {
            return PYMB_FRAME_BAD_LENGTH;
        }
        return PYMB_FRAME_OK;
    case 0x03:
    case 0x04:
    case 0x17:
        if (req_len < 5 || rsp_len < 2) {
            return req_len < 5 ? PYMB_FRAME_INVALID : PYMB_FRAME_BAD_LENGTH;
        }
        nb = be16(req + 3); /* for 0x17 the read quantity comes first too */
        if (rsp[1] != 2 * nb || rsp_len != 2u + rsp[1]) {
            return PYMB_FRAME_BAD_LENGTH;
        }
        return PYMB_FRAME_OK;
    case 0x05:
    case 0x06:
    case 0x16:
        if (rsp_len != req_len) {
            return PYMB_FRAME_BAD_LENGTH;
        }
        return memcmp(req, rsp, req_len) == 0 ? PYMB_FRAME_OK : PYMB_FRAME_BAD_ECHO;
    case 0x0F:
    case 0x10:
        if (req_len < 5) {
            return PYMB_FRAME_INVALID;
        }
        if (rsp_len != 5) {
            return PYMB_FRAME_BAD_LENGTH;
        }
        return memcmp(req + 1, rsp + 1, 4) == 0 ? PYMB_FRAME_OK : PYMB_FRAME_BAD_ECHO;
    case 0x07:
        return rsp_len == 2 ? PYMB_FRAME_OK : PYMB_FRAME_BAD_LENGTH;
    case 0x11:
        return (rsp_len >= 2 && rsp_len == 2u + rsp[1]) ? PYMB_FRAME_OK
                                                         : PYMB_FRAME_BAD_LENGTH;
    default:
        return PYMB_FRAME_OK; /* a function this file does not know */
    }
}

int pymb_rtu_check_response(const uint8_t *req, size_t req_len, const uint8_t *rsp,
                            size_t rsp_len, int *exception_code)
{
    if (req == NULL || rsp == NULL || req_len < 2) {
        return PYMB_FRAME_INVALID;
    }
    if (rsp_len > PYMB_RTU_MAX_ADU) {
        return PYMB_FRAME_TOO_LONG;
    }
    if (rsp_len < 4) {
        return PYMB_FRAME_BAD_LENGTH;
    }
    if (!pymb_rtu_crc_ok(rsp, rsp_len)) {
        return PYMB_FRAME_BAD_CRC;
    }
    if (rsp[0] != req[0]) {
        return PYMB_FRAME_BAD_SLAVE;
    }
    return pymb_check_response_pdu(req + 1, req_len - 1, rsp + 1, rsp_len - 3,
                                   exception_code);
}
