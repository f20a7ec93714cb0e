/* SPDX-License-Identifier: MIT */
/*
 * test_core.c - known-answer tests of pymb's C core (no Python, no libmodbus).
 *
 * Sources of the expected values are named at each check: the CRC-16/MODBUS
 * catalogue check value, the CoolPro document's worked frames ([CP] ch. 02,
 * 04, 06), and the sensor hub's register descriptions ([HUB] 3, [NOTES]).
 */
#include <errno.h>
#include <math.h>
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
    /* Every table entry, through every single-byte and a long frame. */
    for (i = 0; i < 256; i++) {
        uint8_t b = (uint8_t)i;
        CHECK(pymb_crc16(&b, 1) == crc_bitwise(&b, 1));
    }
    for (i = 0; i < sizeof big; i++) {
        big[i] = (uint8_t)(i * 7 + 3);
    }
    CHECK(pymb_crc16(big, sizeof big) == crc_bitwise(big, sizeof big));

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
}

static int same(double a, double b)
{
    return a == b && signbit(a) == signbit(b);
}

static void test_primitives(void)
{
    const uint16_t uptime[2] = {4464, 1};   /* [CP] ch. 04: 70000 s */
    const uint16_t serial[2] = {0x3039, 0}; /* [CP] ch. 06: 12345 */

    CHECK(same(pymb_sm_tenths(251), 25.1));
    CHECK(same(pymb_sm_tenths(0x8000u | 105u), -10.5));
    CHECK(same(pymb_sm_tenths(0x8000u), -0.0)); /* [NOTES]: -0.0, not a marker */
    CHECK(same(pymb_sm_tenths(0), 0.0));
    CHECK(same(pymb_sm_tenths(0x7FFF), 3276.7));
    CHECK(same(pymb_milli(24500), 24.5));
    CHECK(same(pymb_milli(25800), 25.8));
    const uint16_t zero[2] = {0, 0};
    uint32_t u = 1;

    CHECK(pymb_u32_lo_hi(uptime, &u) == 0 && u == 70000u);
    CHECK(pymb_u32_lo_hi(serial, &u) == 0 && u == 12345u);
    /* 0 is a value like any other: the status says whether it is one. */
    CHECK(pymb_u32_lo_hi(zero, &u) == 0 && u == 0u);
}

static void test_hub_one(void)
{
    double v;
    CHECK(pymb_hub_decode_one(PYMB_HUB_TEMPERATURE, 0xFFFF, 0, &v) == PYMB_OFFLINE && isnan(v));
    CHECK(pymb_hub_decode_one(PYMB_HUB_TEMPERATURE, 0x8000, 0, &v) == PYMB_VALUE &&
          same(v, -0.0));
    CHECK(pymb_hub_decode_one(PYMB_HUB_HUMIDITY, 0x00FF, 0, &v) == PYMB_NO_SENSOR && isnan(v));
    CHECK(pymb_hub_decode_one(PYMB_HUB_HUMIDITY, 0x00FF, 1, &v) == PYMB_VALUE && same(v, 25.5));
    CHECK(pymb_hub_decode_one(PYMB_HUB_HUMIDITY, 0x8000, 1, &v) == PYMB_NO_SENSOR);
    CHECK(pymb_hub_decode_one(PYMB_HUB_HUMIDITY, 0x8000, 0, &v) == PYMB_VALUE &&
          same(v, 32768.0));
    CHECK(pymb_hub_decode_one(PYMB_HUB_HUMIDITY, 456, 1, &v) == PYMB_VALUE && same(v, 45.6));
    CHECK(pymb_hub_decode_one(PYMB_HUB_HUMIDITY, 45, 0, &v) == PYMB_VALUE && same(v, 45.0));
    CHECK(pymb_hub_decode_one(PYMB_HUB_HUMIDITY, 0xFFFF, 1, &v) == PYMB_OFFLINE);
    CHECK(pymb_hub_decode_one(PYMB_HUB_PRESSURE, 101, 0, &v) == PYMB_VALUE && same(v, 101.0));
    CHECK(pymb_hub_decode_one(PYMB_HUB_VOLTAGE, 3300, 0, &v) == PYMB_VALUE && same(v, 3300.0));
    CHECK(pymb_hub_decode_one(PYMB_HUB_RSSI, 0xFFB5, 0, &v) == PYMB_VALUE && same(v, -75.0));
    CHECK(pymb_hub_decode_one(PYMB_HUB_RSSI, 0xFFFF, 0, &v) == PYMB_OFFLINE);
    v = 0.0;
    errno = 0;
    CHECK(pymb_hub_decode_one((pymb_hub_block)7, 0, 0, &v) == -1 && errno == EINVAL &&
          isnan(v));
    CHECK(pymb_hub_decode_one((pymb_hub_block)-1, 0, 0, &v) == -1);
}

static void test_hub_block(void)
{
    uint16_t regs[PYMB_HUB_REGISTERS];
    double values[PYMB_HUB_REGISTERS];
    uint8_t states[PYMB_HUB_REGISTERS];
    uint8_t tenths[PYMB_HUB_CHANNELS];
    pymb_hub_request rq;
    unsigned b, c, ch = 100;

    for (b = 0; b < PYMB_HUB_BLOCKS; b++) {
        for (c = 0; c < PYMB_HUB_CHANNELS; c++) {
            regs[b * 100 + c] = (uint16_t)(b * 1000 + c);
        }
    }
    for (c = 0; c < PYMB_HUB_CHANNELS; c++) {
        tenths[c] = (uint8_t)(c % 2);
    }
    regs[0] = 0xFFFF;           /* channel 1 temperature offline */
    regs[100 + 2] = 0x00FF;     /* channel 3 humidity, 1 % unit: no humidity */
    regs[100 + 3] = 0x8000;     /* channel 4 humidity, 0.1 % unit: no humidity */
    regs[500 + 9] = 0xFF9C;     /* channel 10 RSSI -100 dBm */
    regs[600 + 99] = 0x8001;    /* channel 100 temperature 2: -0.1 */

    memset(&rq, 0, sizeof rq);
    rq.regs = regs;
    rq.channels = ch;
    rq.humidity_tenths = tenths;
    rq.read_mask = PYMB_HUB_ALL_BLOCKS & ~0x40u;
    rq.unsupported = 0x40u;
    rq.values = values;
    rq.states = states;
    rq.out_len = sizeof values / sizeof values[0];
    CHECK(pymb_hub_decode(&rq) == 0);
    CHECK(states[0] == PYMB_OFFLINE && isnan(values[0]));
    CHECK(states[1] == PYMB_VALUE && same(values[1], 0.1));
    CHECK(states[ch + 2] == PYMB_NO_SENSOR);
    CHECK(states[ch + 3] == PYMB_NO_SENSOR);
    CHECK(same(values[ch + 5], 1005.0 / 10.0)); /* channel 6: 0.1 % unit */
    CHECK(same(values[ch + 4], 1004.0));        /* channel 5: 1 % unit */
    CHECK(same(values[5 * ch + 9], -100.0));
    CHECK(same(values[3 * ch + 7], 3007.0));
    CHECK(states[6 * ch + 99] == PYMB_UNSUPPORTED && isnan(values[6 * ch + 99]));

    /* Fewer channels: block-major with the smaller stride. */
    ch = 50;
    rq.channels = ch;
    rq.humidity_tenths = NULL;
    rq.read_mask = PYMB_HUB_ALL_BLOCKS;
    rq.unsupported = 0;
    rq.out_len = 7 * 50;
    CHECK(pymb_hub_decode(&rq) == 0);
    CHECK(same(values[6 * ch + 49], 604.9));
    CHECK(same(values[ch + 5], 100.5)); /* NULL tenths: all 0.1 % */

    /* Blocks not read: unsupported or simply not asked for; registers not
     * wanted inside a read block. */
    {
        uint8_t wanted[PYMB_HUB_BITMAP_BYTES] = {0};
        wanted[0] = 0x05; /* channels 1 and 3 of the temperature block */
        rq.channels = 10;
        rq.wanted = wanted;
        rq.read_mask = 0x01u;
        rq.unsupported = 0x40u;
        rq.out_len = 70;
        CHECK(pymb_hub_decode(&rq) == 0);
        rq.wanted = NULL;
        CHECK(states[0] == PYMB_OFFLINE && states[1] == PYMB_NOT_READ && isnan(values[1]));
        CHECK(states[2] == PYMB_VALUE && same(values[2], 0.2));
        CHECK(states[10] == PYMB_NOT_READ && states[60] == PYMB_UNSUPPORTED);
    }

    /* Bad arguments write nothing. */
    errno = 0;
    states[0] = 0xAA;
    rq.read_mask = 0x7F;
    rq.unsupported = 0;
    rq.channels = 0;
    rq.out_len = 700;
    CHECK(pymb_hub_decode(&rq) == -1 && errno == EINVAL && states[0] == 0xAA);
    rq.channels = 101;
    rq.out_len = 707;
    CHECK(pymb_hub_decode(&rq) == -1);
    rq.channels = 100;
    rq.out_len = 699;
    CHECK(pymb_hub_decode(&rq) == -1);
    rq.out_len = 700;
    rq.regs = NULL;
    CHECK(pymb_hub_decode(&rq) == -1);
    rq.regs = regs;
    rq.states = NULL;
    CHECK(pymb_hub_decode(&rq) == -1);
    CHECK(pymb_hub_decode(NULL) == -1);
    rq.states = states;
    CHECK(pymb_hub_decode(&rq) == 0 && states[0] != 0xAA);
}

static void test_coolpro(void)
{
    /* [CP] ch. 02 / 04: 24.5 V, 3.25 A, 24.0 V, 3.20 A, 25.8 degC, 70000 s. */
    const uint16_t tele[8] = {0x5FB4, 0x0CB2, 0x5DC0, 0x0C80, 0x64C8, 4464, 1, 0x8041};
    const uint16_t ident[8] = {0x3039, 0, 2, 1, 0, 0, 0x5E00, 0x6A50};
    pymb_coolpro_telemetry t;
    pymb_coolpro_identity id;

    CHECK(pymb_coolpro_decode_telemetry(tele, 8, &t) == 0);
    CHECK(same(t.input_voltage_v, 24.5) && same(t.input_current_a, 3.25));
    CHECK(same(t.output_voltage_v, 24.0) && same(t.output_current_a, 3.2));
    CHECK(same(t.temperature_c, 25.8));
    CHECK(t.uptime_s == 70000u);
    CHECK(t.status == 0x8041); /* reserved bit 15 kept */
    CHECK(pymb_coolpro_decode_telemetry(tele, 7, &t) == -1);

    CHECK(pymb_coolpro_decode_identity(ident, 8, &id) == 0);
    CHECK(id.serial_number == 12345u && id.hardware_revision == 2);
    CHECK(id.firmware_major == 1 && id.firmware_minor == 0 && id.firmware_patch == 0);
    CHECK(id.manufactured == 0x6A505E00u);
    errno = 0;
    CHECK(pymb_coolpro_decode_identity(NULL, 8, &id) == -1 && errno == EINVAL);
    errno = 0;
    {
        uint32_t u = 7;
        CHECK(pymb_u32_lo_hi(NULL, &u) == -1 && errno == EINVAL && u == 7u);
        errno = 0;
        CHECK(pymb_u32_lo_hi(ident, NULL) == -1 && errno == EINVAL);
    }
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
    CHECK(!PYMB_VERSION_CHECK(PYMB_VERSION_MAJOR + 1, 0, 0));
    CHECK(!PYMB_VERSION_CHECK(PYMB_VERSION_MAJOR, PYMB_VERSION_MINOR, PYMB_VERSION_PATCH + 1));
}

int main(void)
{
    test_crc();
    test_frame_lengths();
    test_check_response();
    test_primitives();
    test_hub_one();
    test_hub_block();
    test_coolpro();
    test_errors_and_version();
    return check_report();
}
