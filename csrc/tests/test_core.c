/* SPDX-License-Identifier: MIT */
/*
 * test_core.c - known-answer tests of pymb's C core (no Python, no libmodbus).
 *
 * Sources of the expected values are named at each check: the CRC-16/MODBUS
 * catalogue check value, and the frames of [MB-AP] and [MB-SL]. The map
 * decoder's tests are test_map.c's.
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "../pymb.h"
#include "check.h"
#include "crc_ref.h" /* bit-by-bit, to check the table */

static void test_crc(void)
{
    const uint8_t check[] = "123456789";
    const uint8_t req[] = {0x28, 0x04, 0x00, 0x00, 0x00, 0x01};
    const uint8_t rsp[] = {0x28, 0x04, 0x02, 0x5F, 0xB4};
    uint8_t frame[8] = {0x28, 0x04, 0x00, 0x00, 0x00, 0x01};
    uint8_t big[255];
    size_t i;

    /* CRC-16/MODBUS catalogue check value. */
    CHECK(pymb_crc16(check, 9) == 0x4B37);
    /* [CP] ch. 04 worked CRCs. */
    CHECK(pymb_crc16(req, sizeof req) == 0x3336);
    CHECK(pymb_crc16(rsp, sizeof rsp) == 0x71DD);
    /* Empty input: the initial value. */
    CHECK(pymb_crc16(check, 0) == 0xFFFF);
    CHECK(pymb_crc16(NULL, 5) == 0xFFFF);
    /* Incremental equals one-shot. */
    CHECK(pymb_crc16_update(pymb_crc16(check, 4), check + 4, 5) == 0x4B37);
    /* Every entry of the byte table, through every single byte; every entry
     * of the eight tables of an eight-byte step, through every value at each
     * of its eight places; a long frame at every length (the steps of eight
     * and the bytes left over). */
    for (i = 0; i < 256; i++) {
        uint8_t b = (uint8_t)i, eight[8] = {0, 0, 0, 0, 0, 0, 0, 0};
        size_t at;
        CHECK(pymb_crc16(&b, 1) == crc_bitwise(&b, 1));
        for (at = 0; at < 8; at++) {
            eight[at] = b;
            CHECK(pymb_crc16(eight, 8) == crc_bitwise(eight, 8));
            eight[at] = 0;
        }
    }
    for (i = 0; i < sizeof big; i++) {
        big[i] = (uint8_t)(i * 7 + 3);
    }
    for (i = 0; i <= sizeof big; i++) {
        CHECK(pymb_crc16(big, i) == crc_bitwise(big, i));
    }

    /* Appended low byte first: wire 28 04 00 00 00 01 36 33 ([CP] ch. 04). */
    CHECK(pymb_rtu_append_crc(frame, 6, sizeof frame) == 8);
    CHECK(frame[6] == 0x36 && frame[7] == 0x33);
    CHECK(pymb_rtu_crc_ok(frame, 8));
    frame[3] ^= 0x01;
    CHECK(!pymb_rtu_crc_ok(frame, 8));
    errno = 0;
    CHECK(pymb_rtu_append_crc(frame, 7, 8) == -1 && errno == EINVAL); /* no room */
    errno = 0;
    CHECK(pymb_rtu_append_crc(frame, 9, 8) == -1 && errno == EINVAL); /* len beyond cap */
    CHECK(pymb_rtu_append_crc(big, 255, 300) == -1); /* no RTU frame is that long */
    CHECK(pymb_rtu_append_crc(NULL, 1, 8) == -1);
    CHECK(pymb_rtu_crc_ok(frame, 2) == 0);
    errno = 0;
    CHECK(pymb_rtu_crc_ok(NULL, 8) == -1 && errno == EINVAL);
}

static size_t with_crc(uint8_t *f, size_t n)
{
    return pymb_rtu_append_crc(f, n, PYMB_RTU_MAX_ADU);
}

static void test_frame_lengths(void)
{
    uint8_t r[8] = {0x28, 0x04, 0x02};
    uint8_t big[3] = {0x01, 0x03, 0xFF};

    CHECK(pymb_rtu_response_length(r, 1) == PYMB_FRAME_INCOMPLETE);
    CHECK(pymb_rtu_response_length(r, 2) == PYMB_FRAME_INCOMPLETE);
    CHECK(pymb_rtu_response_length(r, 3) == 7); /* [CP] 28 04 02 5F B4 CRC */
    r[1] = 0x84;
    CHECK(pymb_rtu_response_length(r, 2) == 5);
    r[1] = 0x06;
    CHECK(pymb_rtu_response_length(r, 2) == 8);
    r[1] = 0x10;
    CHECK(pymb_rtu_response_length(r, 2) == 8);
    r[1] = 0x16;
    CHECK(pymb_rtu_response_length(r, 2) == 10);
    CHECK(pymb_rtu_response_length(big, 3) == PYMB_FRAME_TOO_LONG);
    CHECK(pymb_rtu_response_length(NULL, 9) == PYMB_FRAME_INCOMPLETE);
    r[1] = 0x07;
    CHECK(pymb_rtu_response_length(r, 2) == 5);
    /* Diagnostics (0x08), device identification (0x2B), user codes: only the
     * line's silence tells where the reply ends. */
    r[1] = 0x08;
    CHECK(pymb_rtu_response_length(r, 2) == PYMB_FRAME_BAD_FUNCTION);
    r[1] = 0x2B;
    CHECK(pymb_rtu_response_length(r, 8) == PYMB_FRAME_BAD_FUNCTION);
    r[1] = 0x41;
    CHECK(pymb_rtu_response_length(r, 2) == PYMB_FRAME_BAD_FUNCTION);

    r[1] = 0x03;
    CHECK(pymb_rtu_request_length(r, 2) == 8);
    r[1] = 0x10;
    CHECK(pymb_rtu_request_length(r, 6) == PYMB_FRAME_INCOMPLETE);
    r[6] = 4;
    CHECK(pymb_rtu_request_length(r, 7) == 13);
    r[1] = 0x42;
    CHECK(pymb_rtu_request_length(r, 7) == PYMB_FRAME_BAD_FUNCTION);
}

static void test_check_response(void)
{
    uint8_t req[8] = {0x28, 0x04, 0x00, 0x00, 0x00, 0x04};
    /* [CP] ch. 02: Vin, Iin, Vout, Iout. */
    uint8_t rsp[16] = {0x28, 0x04, 0x08, 0x5F, 0xB4, 0x0C, 0xB2, 0x5D, 0xC0, 0x0C, 0x80};
    uint8_t exc[8] = {0x28, 0x84, 0x02};
    uint8_t wreq[8] = {0x28, 0x06, 0x00, 0x00, 0x00, 0x2A};
    uint8_t wrsp[8] = {0x28, 0x06, 0x00, 0x00, 0x00, 0x2A};
    size_t n = with_crc(rsp, 11);
    int code = 0;

    CHECK(n == 13);
    CHECK(pymb_rtu_check_response(req, 6, rsp, n, NULL) == PYMB_FRAME_OK);
    rsp[4] ^= 0x40;
    CHECK(pymb_rtu_check_response(req, 6, rsp, n, NULL) == PYMB_FRAME_BAD_CRC);
    rsp[4] ^= 0x40;
    req[0] = 0x29;
    CHECK(pymb_rtu_check_response(req, 6, rsp, n, NULL) == PYMB_FRAME_BAD_SLAVE);
    req[0] = 0x28;
    req[5] = 0x03; /* asked for 3 registers, got 4 */
    CHECK(pymb_rtu_check_response(req, 6, rsp, n, NULL) == PYMB_FRAME_BAD_LENGTH);
    req[5] = 0x04;
    req[1] = 0x03; /* asked holding, got input */
    CHECK(pymb_rtu_check_response(req, 6, rsp, n, NULL) == PYMB_FRAME_BAD_FUNCTION);
    req[1] = 0x04;

    n = with_crc(exc, 3);
    CHECK(pymb_rtu_check_response(req, 6, exc, n, &code) == PYMB_FRAME_EXCEPTION);
    CHECK(code == 2);

    /* [CP] ch. 06: write device address 42, echoed. */
    n = with_crc(wrsp, 6);
    CHECK(pymb_rtu_check_response(wreq, 6, wrsp, n, NULL) == PYMB_FRAME_OK);
    wrsp[5] = 0x2B;
    n = with_crc(wrsp, 6);
    CHECK(pymb_rtu_check_response(wreq, 6, wrsp, n, NULL) == PYMB_FRAME_BAD_ECHO);
    /* The request is passed without its CRC (the header says so): with it,
     * an echo cannot match. */
    wrsp[5] = 0x2A;
    n = with_crc(wrsp, 6);
    CHECK(with_crc(wreq, 6) == 8);
    CHECK(pymb_rtu_check_response(wreq, 6, wrsp, n, NULL) == PYMB_FRAME_OK);
    CHECK(pymb_rtu_check_response(wreq, 8, wrsp, n, NULL) == PYMB_FRAME_BAD_LENGTH);

    CHECK(pymb_rtu_check_response(req, 6, rsp, 3, NULL) == PYMB_FRAME_BAD_LENGTH);
    CHECK(pymb_rtu_check_response(req, 6, rsp, 300, NULL) == PYMB_FRAME_TOO_LONG);
    CHECK(pymb_rtu_check_response(NULL, 6, rsp, 13, NULL) == PYMB_FRAME_INVALID);
    CHECK(strcmp(pymb_frame_strerror(PYMB_FRAME_BAD_CRC), "bad CRC") == 0);
    CHECK(strncmp(pymb_frame_strerror(PYMB_FRAME_BAD_HEADER), "MBAP", 4) == 0);
    CHECK(strncmp(pymb_frame_strerror(PYMB_FRAME_BAD_TEXT), "ASCII", 5) == 0);
    CHECK(strcmp(pymb_frame_strerror(PYMB_FRAME_BAD_TID), "reply to another transaction id") == 0);
}

static void test_errors_and_version(void)
{
    char want[32];

    /* libmodbus's texts for its codes ([MB-AP] 7 for the exceptions). */
    CHECK(strcmp(pymb_strerror(PYMB_EMBXILADD), "Illegal data address") == 0);
    CHECK(strcmp(pymb_strerror(PYMB_EMBBADCRC), "Invalid CRC") == 0);
    CHECK(strcmp(pymb_strerror(PYMB_EMBBADSLAVE), "Response not from requested slave") == 0);
    CHECK(strcmp(pymb_strerror(EINVAL), strerror(EINVAL)) == 0);
    CHECK(strcmp(pymb_strerror(ETIMEDOUT), strerror(ETIMEDOUT)) == 0);
    CHECK(pymb_strerror(PYMB_ENOBASE + 9) != NULL); /* no exception 09: strerror's */
    CHECK(strcmp(pymb_strerror(PYMB_EXCEPTION_ENOBASE + 0x0C),
                 "Exception code not defined by the Modbus specification") == 0);
    CHECK(strcmp(pymb_strerror(PYMB_EXCEPTION_ENOBASE + 0xFF),
                 "Exception code not defined by the Modbus specification") == 0);
    CHECK(strcmp(pymb_strerror(PYMB_EXCEPTION_ENOBASE + 0x100),
                 "Exception code not defined by the Modbus specification") != 0);

    snprintf(want, sizeof want, "%d.%d.%d", PYMB_VERSION_MAJOR, PYMB_VERSION_MINOR,
             PYMB_VERSION_PATCH);
    CHECK(strcmp(pymb_version(), want) == 0);
    CHECK(strcmp(PYMB_VERSION_STRING, want) == 0);
    CHECK(PYMB_VERSION_CHECK(PYMB_VERSION_MAJOR, PYMB_VERSION_MINOR, PYMB_VERSION_PATCH));
    CHECK(PYMB_VERSION_CHECK(0, 0, 1));
    CHECK(PYMB_VERSION_CHECK(1, 0, 0)); /* libpymb.so.1: the 1.0 ABI */
    CHECK(!PYMB_VERSION_CHECK(PYMB_VERSION_MAJOR + 1, 0, 0));
    CHECK(!PYMB_VERSION_CHECK(PYMB_VERSION_MAJOR, PYMB_VERSION_MINOR, PYMB_VERSION_PATCH + 1));
}

int main(void)
{
    test_crc();
    test_frame_lengths();
    test_check_response();
    test_errors_and_version();
    return check_report();
}
