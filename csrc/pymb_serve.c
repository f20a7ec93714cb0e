/* SPDX-License-Identifier: MIT */
/*
 * pymb_serve.c - a Modbus TCP server's requests taken and checked, its
 * replies framed (by the one MBAP framing, pymbi_mbap_frame: pymb_frame.c;
 * see pymb_serve.h). No allocation, no I/O, no state between
 * calls; reads only inside the lengths it is given.
 */
#include <errno.h>
#include <string.h>

#include "pymb.h"
#include "pymb_master.h"
#include "pymb_serve.h"

#define EX_FUNCTION 1 /* [MB-APP] 7: illegal function */
#define EX_ADDRESS 2  /* illegal data address */
#define EX_VALUE 3    /* illegal data value */

static unsigned u16(const uint8_t *p)
{
    return (unsigned)p[0] << 8 | p[1];
}

/* address, quantity in 1..max, and address + quantity within 65536 */
static int range(const uint8_t *d, unsigned max)
{
    unsigned address = u16(d), quantity = u16(d + 2);
    if (quantity < 1 || quantity > max)
        return EX_VALUE;
    return address + quantity > 0x10000u ? EX_ADDRESS : 0;
}

int pymbi_srv_check_pdu(const uint8_t *pdu, size_t len)
{
    const uint8_t *d;
    size_t n;
    unsigned q, bc;
    int r;

    if (pdu == NULL || len < 1 || len > PYMBI_SRV_MAX_PDU)
        return EX_VALUE;
    if (pdu[0] == 0 || pdu[0] & 0x80u)
        return EX_FUNCTION;
    d = pdu + 1;
    n = len - 1;
    switch (pdu[0]) {
    case 0x01: /* read coils [MB-APP] 6.1 */
    case 0x02: /* read discrete inputs 6.2 */
        return n != 4 ? EX_VALUE : range(d, 2000);
    case 0x03: /* read holding registers 6.3 */
    case 0x04: /* read input registers 6.4 */
        return n != 4 ? EX_VALUE : range(d, 125);
    case 0x05: /* write single coil 6.5: 0x0000 or 0xFF00 */
        if (n != 4)
            return EX_VALUE;
        q = u16(d + 2);
        return q == 0x0000u || q == 0xFF00u ? 0 : EX_VALUE;
    case 0x06: /* write single register 6.6 */
        return n != 4 ? EX_VALUE : 0;
    case 0x07: /* read exception status 6.7 */
    case 0x0B: /* get comm event counter 6.9 */
    case 0x0C: /* get comm event log 6.10 */
    case 0x11: /* report server id 6.13 */
        return n != 0 ? EX_VALUE : 0;
    case 0x08: /* diagnostics 6.8: sub-function and its data */
        return n < 2 ? EX_VALUE : 0;
    case 0x0F: /* write multiple coils 6.11 */
        if (n < 6)
            return EX_VALUE;
        q = u16(d + 2);
        bc = d[4];
        if (q < 1 || q > 0x7B0u || bc != (q + 7) / 8 || n != 5 + bc)
            return EX_VALUE;
        return range(d, 0x7B0u);
    case 0x10: /* write multiple registers 6.12 */
        if (n < 6)
            return EX_VALUE;
        q = u16(d + 2);
        bc = d[4];
        if (q < 1 || q > 0x7Bu || bc != 2 * q || n != 5 + bc)
            return EX_VALUE;
        return range(d, 0x7Bu);
    case 0x14: /* read file record 6.14: byte count 0x07..0xF5, 7 bytes a sub-request */
    case 0x15: /* write file record 6.15: 0x09..0xFB, 7 bytes and the record a sub-request */
        if (n < 1)
            return EX_VALUE;
        bc = d[0];
        if (pdu[0] == 0x14 ? bc < 7 || bc > 0xF5u : bc < 9 || bc > 0xFBu)
            return EX_VALUE;
        return n != 1 + (size_t)bc ? EX_VALUE : 0;
    case 0x16: /* mask write register 6.16 */
        return n != 6 ? EX_VALUE : 0;
    case 0x17: /* read/write multiple registers 6.17 */
        if (n < 9)
            return EX_VALUE;
        q = u16(d + 6);
        bc = d[8];
        if (q < 1 || q > 0x79u || bc != 2 * q || n != 9 + bc)
            return EX_VALUE;
        r = range(d, 0x7Du);
        return r ? r : range(d + 4, 0x79u);
    case 0x18: /* read FIFO queue 6.18 */
        return n != 2 ? EX_VALUE : 0;
    case 0x2B: /* encapsulated interface transport 6.19: MEI type and its data */
        return n < 1 ? EX_VALUE : 0;
    default: /* user-defined and other codes: only the device can judge them */
        return 0;
    }
}

int pymbi_srv_take(const uint8_t *buf, size_t len, pymbi_srv_req *req)
{
    int n;

    if ((buf == NULL && len > 0) || req == NULL) {
        errno = EINVAL;
        return -1;
    }
    /* [MB-TCP] 3.1.3, the one MBAP length rule: the header is judged as soon
     * as its bytes are in, so a client that sends garbage is closed without
     * waiting for more */
    n = pymbi_mbap_length(buf, len);
    if (n == PYMB_FRAME_INCOMPLETE || (n > 0 && len < (size_t)n))
        return 0;
    if (n < 0)
        return -1;
    memset(req, 0, sizeof *req);
    req->tid = (uint16_t)u16(buf);
    req->unit = buf[6];
    req->function = buf[7];
    req->pdu_len = (uint16_t)(n - PYMBI_SRV_MBAP);
    req->exception = (uint8_t)pymbi_srv_check_pdu(buf + PYMBI_SRV_MBAP, req->pdu_len);
    return n;
}

int pymbi_srv_reply(uint16_t tid, uint8_t unit, const uint8_t *pdu, size_t pdu_len,
                    uint8_t *out, size_t out_cap)
{
    if (pdu == NULL || out == NULL || pdu_len < 1 || pdu_len > PYMBI_SRV_MAX_PDU ||
        out_cap < PYMBI_SRV_MBAP + pdu_len) {
        errno = EINVAL;
        return -1;
    }
    return pymbi_mbap_frame(tid, unit, pdu, pdu_len, out);
}

int pymbi_srv_exception(uint16_t tid, uint8_t unit, uint8_t function, uint8_t code,
                        uint8_t *out, size_t out_cap)
{
    uint8_t pdu[2];
    if (code == 0) {
        errno = EINVAL;
        return -1;
    }
    pdu[0] = (uint8_t)(function | 0x80u);
    pdu[1] = code;
    return pymbi_srv_reply(tid, unit, pdu, sizeof pdu, out, out_cap);
}
