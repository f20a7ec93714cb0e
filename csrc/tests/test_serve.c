/* SPDX-License-Identifier: MIT */
/*
 * test_serve.c - known-answer tests of the requests a Modbus TCP server takes
 * (pymbi_srv_take, pymbi_srv_check_pdu) and the replies it frames
 * (pymbi_srv_reply, pymbi_srv_exception): no Python, no libmodbus.
 *
 * Sources: [MB-TCP] 3.1.3 (MBAP); [MB-APP] 6.1-6.19 (each function's request
 * and its quantities), 7 (exception codes); the request examples of
 * [MB-APP] 6.3 (read holding registers 108..110: 03 00 6B 00 03) and 6.12
 * (write 00 0A, 01 02 to registers 2..3: 10 00 01 00 02 04 00 0A 01 02).
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "../pymb_serve.h"
#include "check.h"

static int check_pdu(const char *hex)
{
    uint8_t pdu[300];
    size_t n = 0;
    unsigned b;
    while (*hex && sscanf(hex, "%2x", &b) == 1) {
        pdu[n++] = (uint8_t)b;
        hex += 2;
        while (*hex == ' ')
            hex++;
    }
    return pymbi_srv_check_pdu(pdu, n);
}

/* A write file record (6.15) of request data length bc: one sub-request,
 * its record of (bc - 7) / 2 registers, the PDU as long as bc says. */
static int check_fc15(unsigned bc)
{
    uint8_t pdu[2 + 0xFF];
    memset(pdu, 0x5A, sizeof pdu);
    pdu[0] = 0x15;
    pdu[1] = (uint8_t)bc;
    pdu[2] = 6;
    pdu[7] = 0;
    pdu[8] = (uint8_t)((bc - 7) / 2);
    return pymbi_srv_check_pdu(pdu, 2 + bc);
}

static void test_documents_examples(void)
{
    /* [MB-APP] 6.3 and 6.12 request examples */
    CHECK(check_pdu("03 006B 0003") == 0);
    CHECK(check_pdu("10 0001 0002 04 000A 0102") == 0);
    /* 6.1 read coils 20..38, 6.5 write coil 173 ON, 6.6 write register 1 = 3 */
    CHECK(check_pdu("01 0013 0013") == 0);
    CHECK(check_pdu("05 00AC FF00") == 0);
    CHECK(check_pdu("06 0001 0003") == 0);
    /* 6.11 write 10 coils from 20: byte count 2 */
    CHECK(check_pdu("0F 0013 000A 02 CD01") == 0);
    /* 6.16 mask write, 6.17 read/write, 6.18 FIFO, 6.19 device id */
    CHECK(check_pdu("16 0004 00F2 0025") == 0);
    CHECK(check_pdu("17 0003 0006 000E 0003 06 00FF 00FF 00FF") == 0);
    CHECK(check_pdu("18 04DE") == 0);
    CHECK(check_pdu("2B 0E 01 00") == 0);
    CHECK(check_pdu("07") == 0);
    CHECK(check_pdu("11") == 0);
    CHECK(check_pdu("08 0000 A537") == 0);
    CHECK(check_pdu("14 0E 06 0004 0001 0002 06 0003 0009 0002") == 0);
}

static void test_refusals(void)
{
    CHECK(check_pdu("00") == 1);             /* function code 0 */
    CHECK(check_pdu("83 0000 0001") == 1);   /* an exception code as a request */
    CHECK(check_pdu("03 0000 0000") == 3);   /* quantity 0 */
    CHECK(check_pdu("03 0000 007E") == 3);   /* 126 registers */
    CHECK(check_pdu("03 0000 007D") == 0);   /* 125: the most */
    CHECK(check_pdu("03 FFFF 0002") == 2);   /* runs past 65535 */
    CHECK(check_pdu("03 FFFF 0001") == 0);
    CHECK(check_pdu("03 0000 00") == 3);     /* short */
    CHECK(check_pdu("03 0000 0001 00") == 3); /* long */
    CHECK(check_pdu("01 0000 07D1") == 3);   /* 2001 coils */
    CHECK(check_pdu("01 0000 07D0") == 0);
    CHECK(check_pdu("05 0000 0001") == 3);   /* coil value other than 0000/FF00 */
    CHECK(check_pdu("10 0000 0002 03 000A 01") == 3);   /* byte count != 2 x quantity */
    CHECK(check_pdu("10 0000 0002 04 000A 01") == 3);   /* fewer bytes than the count */
    CHECK(check_pdu("10 0000 007C F8") == 3);           /* 124 registers */
    CHECK(check_pdu("0F 0000 0009 01 FF") == 3);        /* 9 coils need 2 bytes */
    CHECK(check_pdu("17 0000 007E 0000 0001 02 0000") == 3); /* read 126 */
    CHECK(check_pdu("17 0000 0001 0000 007A F4") == 3);      /* write 122 */
    CHECK(check_pdu("16 0000 FFFF") == 3);
    CHECK(check_pdu("07 00") == 3);
    CHECK(check_pdu("08 00") == 3);
    CHECK(check_pdu("18") == 3);
    CHECK(check_pdu("14 06 06 0004 0001 00") == 3);      /* byte count under 7 */
    /* 6.15 write file record: request data length 0x09..0xFB (one sub-request of
     * 7 bytes and a record of 1..122 registers) */
    CHECK(check_pdu("15 0D 06 0004 0007 0003 06AF 04BE 100D") == 0); /* 6.15's example */
    CHECK(check_pdu("15 07 06 0004 0007 0000") == 3);    /* no record */
    CHECK(check_pdu("15 08 06 0004 0007 0000 00") == 3);
    CHECK(check_pdu("15 0E 06 0004 0007 0003 06AF 04BE 100D") == 3); /* fewer bytes */
    CHECK(check_fc15(0xFB) == 0);                        /* 122 registers: the most */
    CHECK(check_fc15(0xFC) == 3);
    CHECK(check_pdu("14 F6") == 3);                      /* 6.14: at most 0xF5 */
    CHECK(check_pdu("41 0102") == 0);                    /* user-defined: forwarded */
    CHECK(pymbi_srv_check_pdu(NULL, 1) == 3);
}

static void test_take(void)
{
    /* [MB-TCP] 3.1.3: tid 0x1234, protocol 0, length 6, unit 0x11, read 03 */
    const uint8_t frame[] = {0x12, 0x34, 0, 0, 0, 6, 0x11, 3, 0, 0x6B, 0, 3};
    uint8_t two[2 * sizeof frame];
    pymbi_srv_req r;
    size_t i;

    CHECK(pymbi_srv_take(frame, sizeof frame, &r) == (int)sizeof frame);
    CHECK(r.tid == 0x1234 && r.unit == 0x11 && r.function == 3 && r.pdu_len == 5);
    CHECK(r.exception == 0);
    /* every prefix asks for more */
    for (i = 0; i < sizeof frame; i++)
        CHECK(pymbi_srv_take(frame, i, &r) == 0);
    /* two frames glued: the first is taken, then the second */
    memcpy(two, frame, sizeof frame);
    memcpy(two + sizeof frame, frame, sizeof frame);
    two[sizeof frame + 1] = 0x35;
    CHECK(pymbi_srv_take(two, sizeof two, &r) == (int)sizeof frame);
    CHECK(pymbi_srv_take(two + sizeof frame, sizeof frame, &r) == (int)sizeof frame);
    CHECK(r.tid == 0x1235);
    {
        uint8_t bad[sizeof frame];
        memcpy(bad, frame, sizeof frame);
        bad[3] = 1; /* protocol id 1 */
        CHECK(pymbi_srv_take(bad, 4, &r) == -1);
        memcpy(bad, frame, sizeof frame);
        bad[5] = 1; /* length 1: no room for a function code */
        CHECK(pymbi_srv_take(bad, sizeof bad, &r) == -1);
        bad[4] = 1;
        bad[5] = 0; /* length 256 */
        CHECK(pymbi_srv_take(bad, sizeof bad, &r) == -1);
        memcpy(bad, frame, sizeof frame);
        bad[11] = 0; /* quantity 0: taken, answered with exception 03 */
        CHECK(pymbi_srv_take(bad, sizeof bad, &r) == (int)sizeof bad);
        CHECK(r.exception == 3);
    }
    {
        /* the longest frame: length 254 (unit + 253 bytes of PDU) */
        uint8_t big[6 + 254];
        memset(big, 0, sizeof big);
        big[5] = 254;
        big[7] = 0x41;
        CHECK(pymbi_srv_take(big, sizeof big, &r) == (int)sizeof big);
        CHECK(r.pdu_len == 253 && r.exception == 0);
        big[5] = 255;
        CHECK(pymbi_srv_take(big, sizeof big, &r) == -1);
    }
    errno = 0;
    CHECK(pymbi_srv_take(NULL, 3, &r) == -1 && errno == EINVAL);
    CHECK(pymbi_srv_take(frame, sizeof frame, NULL) == -1);
}

static void test_replies(void)
{
    const uint8_t pdu[] = {3, 6, 0x02, 0x2B, 0, 0, 0, 0x64};
    const uint8_t want[] = {0x12, 0x34, 0, 0, 0, 9, 0x11, 3, 6, 0x02, 0x2B, 0, 0, 0, 0x64};
    const uint8_t ex[] = {0x12, 0x34, 0, 0, 0, 3, 0x11, 0x83, 0x0B};
    uint8_t out[PYMBI_SRV_MAX_FRAME];
    uint8_t big[254];

    CHECK(pymbi_srv_reply(0x1234, 0x11, pdu, sizeof pdu, out, sizeof out) == (int)sizeof want);
    CHECK(memcmp(out, want, sizeof want) == 0);
    CHECK(pymbi_srv_exception(0x1234, 0x11, 3, 0x0B, out, sizeof out) == 9);
    CHECK(memcmp(out, ex, sizeof ex) == 0);
    CHECK(pymbi_srv_exception(0x1234, 0x11, 3, 0x0B, out, 8) == -1);
    CHECK(pymbi_srv_exception(0x1234, 0x11, 3, 0, out, sizeof out) == -1);
    CHECK(pymbi_srv_reply(1, 1, pdu, 0, out, sizeof out) == -1);
    memset(big, 0, sizeof big);
    CHECK(pymbi_srv_reply(1, 1, big, 253, out, sizeof out) == 260);
    CHECK(pymbi_srv_reply(1, 1, big, 254, out, sizeof out) == -1);
    CHECK(pymbi_srv_reply(1, 1, big, 253, out, 259) == -1);
}

int main(void)
{
    test_documents_examples();
    test_refusals();
    test_take();
    test_replies();
    return check_report();
}
