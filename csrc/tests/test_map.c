/* SPDX-License-Identifier: MIT */
/*
 * test_map.c - known-answer tests of the table-driven map decoder
 * (pymb_map_decode, pymb_map_order, and the decode made ready:
 * pymbi_map_ready, pymbi_map_run): no Python, no libmodbus.
 *
 * Sources: 230.5 as a float32 is 0x43668000 and each order's registers are
 * what libmodbus 3.1.6's modbus_get_float_abcd/badc/cdab/dcba read as 230.5;
 * the 32- and 64-bit integer vectors are from Telegraf's inputs.modbus test
 * table (plugins/inputs/modbus/modbus_test.go); -1896 x 0.1 = -189.6 and the
 * sign-magnitude and marker rules are the pymb.map/1 contract's section 3.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../pymb.h"
#include "../pymb_map_ready.h"
#include "check.h"

#define SLOTS 16
static double values[SLOTS];
static int64_t ints[SLOTS];
static uint8_t states[SLOTS];
static uint8_t text[64];

static pymb_map_out fresh_out(void)
{
    pymb_map_out out;
    size_t i;
    for (i = 0; i < SLOTS; i++) {
        values[i] = 12345.0;
        ints[i] = 777;
        states[i] = 99;
    }
    memset(text, 0xEE, sizeof text);
    out.values = values;
    out.ints = ints;
    out.states = states;
    out.len = SLOTS;
    out.text = text;
    out.text_len = sizeof text;
    return out;
}

static pymb_map_entry entry(int type, unsigned count, const char *order)
{
    pymb_map_entry e;
    memset(&e, 0, sizeof e);
    e.type = (uint8_t)type;
    e.count = (uint16_t)count;
    e.channels = 1;
    e.stride = (uint16_t)count;
    if (order != NULL && type != PYMB_MAP_STRING && type != PYMB_MAP_RAW &&
        type != PYMB_MAP_BOOL) {
        CHECK(pymb_map_order(order, 2 * (int)count, e.order) == 0);
    }
    return e;
}

/* Decode one entry over regs; returns the return value. */
static int one(pymb_map_entry e, const uint16_t *regs, size_t n)
{
    pymb_map_out out = fresh_out();
    return pymb_map_decode(&e, 1, NULL, 0, regs, n, &out);
}

static void test_order(void)
{
    uint8_t p[8];
    static const uint8_t cdab8[8] = {6, 7, 4, 5, 2, 3, 0, 1};
    static const uint8_t badcfehg[8] = {1, 0, 3, 2, 5, 4, 7, 6};

    CHECK(pymb_map_order("ABCD", 4, p) == 0 && p[0] == 0 && p[1] == 1 && p[2] == 2 && p[3] == 3);
    CHECK(pymb_map_order("CDAB", 4, p) == 0 && p[0] == 2 && p[1] == 3 && p[2] == 0 && p[3] == 1);
    CHECK(pymb_map_order("BADC", 4, p) == 0 && p[0] == 1 && p[1] == 0 && p[2] == 3 && p[3] == 2);
    CHECK(pymb_map_order("DCBA", 4, p) == 0 && p[0] == 3 && p[1] == 2 && p[2] == 1 && p[3] == 0);
    CHECK(pymb_map_order("CDAB", 8, p) == 0 && memcmp(p, cdab8, 8) == 0);
    CHECK(pymb_map_order("BADCFEHG", 8, p) == 0 && memcmp(p, badcfehg, 8) == 0);
    CHECK(pymb_map_order("CDAB", 2, p) == 0 && p[0] == 0 && p[1] == 1);
    CHECK(pymb_map_order("BA", 2, p) == 0 && p[0] == 1 && p[1] == 0);
    /* "BCDA": B arrives first, so A (the value's first byte) is at position 3. */
    CHECK(pymb_map_order("BCDA", 4, p) == 0 && p[0] == 3 && p[1] == 0);
    errno = 0;
    CHECK(pymb_map_order("ABCE", 4, p) == -1 && errno == EINVAL);
    CHECK(pymb_map_order("AB", 4, p) == -1);
    CHECK(pymb_map_order("AABB", 4, p) == -1);
    CHECK(pymb_map_order("ABCD", 3, p) == -1);
    CHECK(pymb_map_order(NULL, 4, p) == -1);
    CHECK(pymb_map_order("ABCD", 4, NULL) == -1);
}

static void test_floats(void)
{
    static const uint16_t abcd[2] = {0x4366, 0x8000}, cdab[2] = {0x8000, 0x4366};
    static const uint16_t badc[2] = {0x6643, 0x0080}, dcba[2] = {0x0080, 0x6643};
    static const uint16_t nan32[2] = {0x7FC0, 0x0001}, one16[1] = {0x3C00};
    static const uint16_t tele16[1] = {0xB814}; /* Telegraf: FLOAT16-IEEE -0.509765625 */
    static const uint16_t sub16[1] = {0x0001};  /* the smallest subnormal, 2^-24 */
    static const uint16_t f64[4] = {0xBF9C, 0x6A40, 0xC347, 0x8F55}; /* Telegraf */

    CHECK(one(entry(PYMB_MAP_F32, 2, "ABCD"), abcd, 2) == 1 && values[0] == 230.5 &&
          states[0] == PYMB_VALUE);
    CHECK(one(entry(PYMB_MAP_F32, 2, "CDAB"), cdab, 2) == 1 && values[0] == 230.5);
    CHECK(one(entry(PYMB_MAP_F32, 2, "BADC"), badc, 2) == 1 && values[0] == 230.5);
    CHECK(one(entry(PYMB_MAP_F32, 2, "DCBA"), dcba, 2) == 1 && values[0] == 230.5);
    CHECK(one(entry(PYMB_MAP_F32, 2, "ABCD"), nan32, 2) == 1 && isnan(values[0]) &&
          states[0] == PYMB_MAP_NAN);
    CHECK(one(entry(PYMB_MAP_F16, 1, "ABCD"), one16, 1) == 1 && values[0] == 1.0);
    CHECK(one(entry(PYMB_MAP_F16, 1, "ABCD"), tele16, 1) == 1 && values[0] == -0.509765625);
    CHECK(one(entry(PYMB_MAP_F16, 1, "ABCD"), sub16, 1) == 1 && values[0] == ldexp(1.0, -24));
    CHECK(one(entry(PYMB_MAP_F64, 4, "ABCD"), f64, 4) == 1 && values[0] == -0.02774907295123737);
}

static void test_integers(void)
{
    static const uint16_t aabb[2] = {0xAABB, 0xCCDD};
    static const uint16_t all[4] = {0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF};
    static const uint16_t big[4] = {0x0020, 0x0000, 0x0000, 0x0001}; /* 2^53 + 1 */
    static const uint16_t neg[1] = {0xF898}; /* -1896 */
    static const uint16_t sm[1] = {0x8000 | 1896}, mzero[1] = {0x8000};
    static const uint16_t half[1] = {0x988D}, bits[1] = {0x180D};
    static const uint16_t ghef[4] = {0xF684, 0xF945, 0xFEBC, 0xFFFF}; /* Telegraf */
    pymb_map_entry e;

    /* Telegraf's INT32/UINT32 rows on AA BB CC DD. */
    CHECK(one(entry(PYMB_MAP_I32, 2, "ABCD"), aabb, 2) == 1 && ints[0] == -1430532899);
    CHECK(one(entry(PYMB_MAP_I32, 2, "DCBA"), aabb, 2) == 1 && ints[0] == -573785174);
    CHECK(one(entry(PYMB_MAP_I32, 2, "BADC"), aabb, 2) == 1 && ints[0] == -1146430004);
    CHECK(one(entry(PYMB_MAP_I32, 2, "CDAB"), aabb, 2) == 1 && ints[0] == -857888069);
    CHECK(one(entry(PYMB_MAP_U32, 2, "CDAB"), aabb, 2) == 1 && ints[0] == 3437079227);
    CHECK(one(entry(PYMB_MAP_I64, 4, "GHEFCDAB"), ghef, 4) == 1 && ints[0] == -1387387292028);
    /* u64 keeps its bit pattern, exactly, above 2^53 too. */
    CHECK(one(entry(PYMB_MAP_U64, 4, "ABCD"), all, 4) == 1 && (uint64_t)ints[0] == UINT64_MAX);
    CHECK(one(entry(PYMB_MAP_U64, 4, "ABCD"), big, 4) == 1 &&
          (uint64_t)ints[0] == 9007199254740993u);
    CHECK(one(entry(PYMB_MAP_I64, 4, "ABCD"), all, 4) == 1 && ints[0] == -1 && values[0] == -1.0);
    /* -1896 x 0.1 is -189.6 (a division by 10), not -189.60000000000002. */
    e = entry(PYMB_MAP_I16, 1, "ABCD");
    e.flags = PYMB_MAP_SCALED;
    e.scale = 0.1;
    e.decimals = 1;
    CHECK(one(e, neg, 1) == 1 && values[0] == -189.6 && ints[0] == -1896);
    e.decimals = 0; /* multiplied: what the rule is there to avoid */
    CHECK(one(e, neg, 1) == 1 && values[0] == -1896 * 0.1);
    e = entry(PYMB_MAP_SM16, 1, "ABCD");
    CHECK(one(e, sm, 1) == 1 && ints[0] == -1896 && values[0] == -1896.0);
    e.flags = PYMB_MAP_SCALED;
    e.scale = 0.1;
    e.decimals = 1;
    CHECK(one(e, sm, 1) == 1 && values[0] == -189.6);
    CHECK(one(e, mzero, 1) == 1 && values[0] == 0.0 && signbit(values[0]));
    e.flags |= PYMB_MAP_OFFSET;
    e.offset = 273.15;
    CHECK(one(e, sm, 1) == 1 && values[0] == -189.6 + 273.15);
    /* Telegraf: INT8L/INT8H of 98 8D, UINT8L/H of 18 0D, bit 3 of 0x180D. */
    CHECK(one(entry(PYMB_MAP_I8_LO, 1, "ABCD"), half, 1) == 1 && ints[0] == -115);
    CHECK(one(entry(PYMB_MAP_I8_HI, 1, "ABCD"), half, 1) == 1 && ints[0] == -104);
    CHECK(one(entry(PYMB_MAP_U8_LO, 1, "ABCD"), bits, 1) == 1 && ints[0] == 13);
    CHECK(one(entry(PYMB_MAP_U8_HI, 1, "BADC"), bits, 1) == 1 && ints[0] == 13);
    e = entry(PYMB_MAP_BIT, 1, "ABCD");
    e.bit = 3;
    CHECK(one(e, bits, 1) == 1 && ints[0] == 1 && values[0] == 1.0);
    e.bit = 14;
    CHECK(one(e, bits, 1) == 1 && ints[0] == 0);
    e = entry(PYMB_MAP_BITS, 1, "ABCD");
    e.bit = 8;
    e.width = 5;
    CHECK(one(e, bits, 1) == 1 && ints[0] == 0x18);
}

static void test_markers_blocks_strings(void)
{
    static const uint16_t regs[8] = {0x8000 | 251, 0xFFFF, 0x0005, 0x00FF,
                                     0x5344, 0x4D31, 0x3230, 0x0000}; /* ..."SDM120" */
    static const uint16_t swapped[2] = {0x4453, 0x314D};
    static const uint16_t latin[2] = {0x41E9, 0x0000};
    static const uint16_t coils[3] = {0, 1, 1};
    pymb_map_marker mk[2] = {{0xFFFF, PYMB_OFFLINE}, {0x00FF, PYMB_NO_SENSOR}};
    pymb_map_entry e[3];
    pymb_map_out out = fresh_out();

    /* a block of 4 sign-magnitude tenths, channel 1 at 0, with two markers */
    e[0] = entry(PYMB_MAP_SM16, 1, "ABCD");
    e[0].channels = 4;
    e[0].stride = 1;
    e[0].flags = PYMB_MAP_SCALED;
    e[0].scale = 0.1;
    e[0].decimals = 1;
    e[0].nmarkers = 2;
    /* a string of 4 registers at 4, text at 0 */
    e[1] = entry(PYMB_MAP_STRING, 4, NULL);
    e[1].first = 4;
    e[1].out = 4;
    e[1].flags = PYMB_MAP_ASCII;
    /* the same registers, raw */
    e[2] = entry(PYMB_MAP_RAW, 4, NULL);
    e[2].first = 4;
    e[2].out = 5;
    CHECK(pymb_map_decode(e, 3, mk, 2, regs, 8, &out) == 6);
    CHECK(values[0] == -25.1 && states[0] == PYMB_VALUE);
    CHECK(isnan(values[1]) && states[1] == PYMB_OFFLINE);
    CHECK(values[2] == 0.5 && states[2] == PYMB_VALUE);
    CHECK(isnan(values[3]) && states[3] == PYMB_NO_SENSOR);
    CHECK(states[4] == PYMB_VALUE && ints[4] == 6 && memcmp(text, "SDM120", 6) == 0);
    CHECK(states[5] == PYMB_VALUE && ints[5] == 4 && isnan(values[5]));
    CHECK(values[6] == 12345.0 && states[6] == 99); /* untouched */

    e[1].count = 2;
    e[1].first = 0;
    e[1].flags = PYMB_MAP_SWAP | PYMB_MAP_ASCII;
    out = fresh_out();
    CHECK(pymb_map_decode(&e[1], 1, NULL, 0, swapped, 2, &out) == 1 && ints[4] == 4 &&
          memcmp(text, "SDM1", 4) == 0);
    e[1].flags = PYMB_MAP_ASCII;
    out = fresh_out();
    CHECK(pymb_map_decode(&e[1], 1, NULL, 0, latin, 2, &out) == 1 &&
          states[4] == PYMB_MAP_INVALID_TEXT);
    e[1].flags = 0; /* latin-1: any byte is text */
    out = fresh_out();
    CHECK(pymb_map_decode(&e[1], 1, NULL, 0, latin, 2, &out) == 1 &&
          states[4] == PYMB_VALUE && ints[4] == 2 && text[1] == 0xE9);
    e[1].flags = PYMB_MAP_LOW_BYTE;
    out = fresh_out();
    CHECK(pymb_map_decode(&e[1], 1, NULL, 0, latin, 2, &out) == 1 && ints[4] == 1 &&
          text[0] == 0xE9);
    /* coils: one element per bit */
    e[0] = entry(PYMB_MAP_BOOL, 1, NULL);
    e[0].channels = 3;
    e[0].stride = 1;
    out = fresh_out();
    CHECK(pymb_map_decode(e, 1, NULL, 0, coils, 3, &out) == 3 && ints[0] == 0 && ints[1] == 1 &&
          values[2] == 1.0);
    /* ints may be NULL */
    out = fresh_out();
    out.ints = NULL;
    CHECK(pymb_map_decode(e, 1, NULL, 0, coils, 3, &out) == 3 && ints[0] == 777);
}

/* A scale taken from another register (SunSpec's W and W_SF), a value under
 * a mask (an Altivar's ETA AND 0x006F) and a marker with don't-care bits (an
 * EM24's overflow: high word 0x7FFF, any low word). */
static void test_scale_from_masks_patterns(void)
{
    uint16_t regs[6] = {3342, 1, 0xFFA3, 0x1234, 0x7FFF, 0x0100};
    pymb_map_marker mk[3] = {{0x006F, 0}, {0xFFFF0000u, PYMB_MAP_MARKER_MASK},
                             {0x7FFF0000u, PYMB_MAP_FIRST_MARKER_STATE}};
    pymb_map_entry e[3];
    pymb_map_out out = fresh_out();

    e[0] = entry(PYMB_MAP_I16, 1, "ABCD");
    e[0].flags = PYMB_MAP_SCALE_FROM;
    e[0].aux = 1;
    e[1] = entry(PYMB_MAP_U16, 1, "ABCD");
    e[1].first = 2;
    e[1].out = 1;
    e[1].flags = PYMB_MAP_MASKED;
    e[1].nmarkers = 1;
    e[2] = entry(PYMB_MAP_I32, 2, "ABCD");
    e[2].first = 4;
    e[2].out = 2;
    e[2].first_marker = 1;
    e[2].nmarkers = 2;
    CHECK(pymb_map_decode(e, 3, mk, 3, regs, 6, &out) == 3);
    CHECK(values[0] == 33420.0 && states[0] == PYMB_VALUE && ints[0] == 3342);
    CHECK(ints[1] == 0x23 && values[1] == 35.0 && states[1] == PYMB_VALUE);
    CHECK(isnan(values[2]) && states[2] == PYMB_MAP_FIRST_MARKER_STATE);
    regs[5] = 0xFFFF; /* any low word */
    regs[1] = 0xFFFF; /* SF -1: divide, as the decimal rule does */
    out = fresh_out();
    CHECK(pymb_map_decode(e, 3, mk, 3, regs, 6, &out) == 3);
    CHECK(values[0] == 334.2 && states[2] == PYMB_MAP_FIRST_MARKER_STATE);
    regs[4] = 0x7FFE; /* no overflow */
    regs[1] = 0x8000; /* SunSpec's not implemented */
    out = fresh_out();
    CHECK(pymb_map_decode(e, 3, mk, 3, regs, 6, &out) == 3);
    CHECK(isnan(values[0]) && states[0] == PYMB_MAP_NO_SCALE);
    CHECK(states[2] == PYMB_VALUE && ints[2] == 0x7FFEFFFF);
    regs[1] = 11; /* out of SunSpec's range */
    out = fresh_out();
    CHECK(pymb_map_decode(e, 1, mk, 3, regs, 6, &out) == 1 && states[0] == PYMB_MAP_NO_SCALE);
    regs[1] = 0x0200; /* SF 2 with its bytes swapped */
    e[0].aux = 1 | PYMB_MAP_SF_SWAPPED;
    out = fresh_out();
    CHECK(pymb_map_decode(e, 1, mk, 3, regs, 6, &out) == 1 && values[0] == 334200.0);
    /* the scale factor must be inside the registers; a mask needs its marker */
    e[0].aux = 6;
    out = fresh_out();
    errno = 0;
    CHECK(pymb_map_decode(e, 1, mk, 3, regs, 6, &out) == -1 && errno == EINVAL &&
          states[0] == 99);
    e[1].nmarkers = 0;
    errno = 0;
    CHECK(pymb_map_decode(&e[1], 1, mk, 3, regs, 6, &out) == -1 && errno == EINVAL);
}

/* Every invalid table fails whole, with EINVAL, and writes nothing. */
static void test_invalid(void)
{
    static const uint16_t regs[4] = {1, 2, 3, 4};
    pymb_map_marker mk[1] = {{1, 16}};
    pymb_map_entry good = entry(PYMB_MAP_U16, 1, "ABCD"), e[2];
    pymb_map_out out;
    int i;

    for (i = 0; i < 14; i++) {
        e[0] = good;
        e[1] = entry(PYMB_MAP_U32, 2, "ABCD");
        switch (i) {
        case 0: e[1].type = PYMB_MAP_TYPES; break;
        case 1: e[1].count = 1; break;               /* not a u32's width */
        case 2: e[1].first = 3; break;               /* runs past regs */
        case 3: e[1].channels = 2; e[1].stride = 2; e[1].first = 1; break;
        case 4: e[1].out = SLOTS; break;             /* no such slot */
        case 5: e[1].order[1] = 0; break;            /* not a permutation */
        case 6: e[1].order[0] = 4; break;            /* outside the value */
        case 7: e[1].nmarkers = 2; break;            /* only one marker given */
        case 8: e[1].decimals = 23; break;
        case 9: e[1].type = PYMB_MAP_BIT; e[1].bit = 32; break;
        case 10: e[1].type = PYMB_MAP_BITS; e[1].bit = 30; e[1].width = 3; break;
        case 11: e[1].type = PYMB_MAP_STRING; e[1].aux = 63; break; /* text too small */
        case 12: e[1].type = PYMB_MAP_BIT; e[1].count = 3; break;
        default: e[1].channels = 0; break;
        }
        out = fresh_out();
        errno = 0;
        CHECK(pymb_map_decode(e, 2, mk, 1, regs, 4, &out) == -1 && errno == EINVAL);
        CHECK(values[0] == 12345.0 && states[0] == 99 && ints[0] == 777);
    }
    out = fresh_out();
    CHECK(pymb_map_decode(NULL, 1, NULL, 0, regs, 4, &out) == -1);
    CHECK(pymb_map_decode(&good, 1, NULL, 0, NULL, 4, &out) == -1);
    CHECK(pymb_map_decode(&good, 1, NULL, 0, regs, 4, NULL) == -1);
    CHECK(pymb_map_decode(&good, 1, NULL, 1, regs, 4, &out) == -1);
    out.text = NULL;
    e[0] = entry(PYMB_MAP_STRING, 2, NULL);
    CHECK(pymb_map_decode(e, 1, NULL, 0, regs, 4, &out) == -1);
    out = fresh_out();
    CHECK(pymb_map_decode(NULL, 0, NULL, 0, NULL, 0, &out) == 0);
}

/* The man page's example. */
static void test_man_page_example(void)
{
    pymb_map_entry e[2];
    double v[2];
    int64_t iv[2];
    uint8_t st[2];
    pymb_map_out out = {v, iv, st, 2, NULL, 0};
    uint16_t regs[3] = {0x8000, 0x4366, 4995};

    memset(e, 0, sizeof e);
    e[0].type = PYMB_MAP_F32;
    e[0].count = 2;
    e[0].channels = 1;
    pymb_map_order("CDAB", 4, e[0].order);
    e[1].type = PYMB_MAP_U16;
    e[1].count = 1;
    e[1].channels = 1;
    e[1].first = 2;
    e[1].out = 1;
    e[1].flags = PYMB_MAP_SCALED;
    e[1].scale = 0.01;
    e[1].decimals = 2;
    pymb_map_order("ABCD", 2, e[1].order);
    CHECK(pymb_map_decode(e, 2, NULL, 0, regs, 3, &out) == 2 && v[0] == 230.5 && v[1] == 49.95);
}

/* A decode made ready: checked once, then each run decodes the registers as
 * they are now, as pymb_map_decode does; a job that is not ready (zeroed, or
 * refused by its checks) decodes nothing. */
static void test_ready(void)
{
    pymb_map_entry e[2];
    double v[2];
    int64_t iv[2];
    uint8_t st[2];
    uint16_t regs[3] = {0x8000, 0x4366, 4995};
    pymbi_map_job job;

    memset(e, 0, sizeof e);
    e[0].type = PYMB_MAP_F32;
    e[0].count = 2;
    e[0].channels = 1;
    pymb_map_order("CDAB", 4, e[0].order);
    e[1].type = PYMB_MAP_I16;
    e[1].count = 1;
    e[1].channels = 1;
    e[1].first = 2;
    e[1].out = 1;
    e[1].flags = PYMB_MAP_SCALED;
    e[1].scale = 0.01;
    e[1].decimals = 2;
    pymb_map_order("ABCD", 2, e[1].order);

    memset(&job, 0, sizeof job);
    errno = 0;
    CHECK(pymbi_map_run(&job) == -1 && errno == EINVAL);
    CHECK(pymbi_map_run(NULL) == -1 && pymbi_map_ready(NULL) == -1);
    job.entries = e;
    job.nentries = 2;
    job.regs = regs;
    job.nregs = 3;
    job.out.values = v;
    job.out.ints = iv;
    job.out.states = st;
    job.out.len = 2;
    CHECK(pymbi_map_ready(&job) == 2 && v[0] == 230.5 && v[1] == 49.95 && iv[1] == 4995);
    regs[2] = (uint16_t)-1896;
    v[1] = 0.0;
    st[1] = 99;
    CHECK(pymbi_map_run(&job) == 2 && v[1] == -18.96 && iv[1] == -1896 && st[1] == PYMB_VALUE);
    regs[0] = 0x0000;
    regs[1] = 0x7FC0; /* a NaN: a state, not a value */
    CHECK(pymbi_map_run(&job) == 2 && st[0] == PYMB_MAP_NAN && isnan(v[0]));

    job.nregs = 2; /* the i16 lies outside the registers: refused, and stays so */
    errno = 0;
    CHECK(pymbi_map_ready(&job) == -1 && errno == EINVAL && job.ready == 0);
    CHECK(pymbi_map_run(&job) == -1);
    job.nregs = 3;
    job.out.len = 1; /* the second slot outside the arrays */
    CHECK(pymbi_map_ready(&job) == -1 && pymbi_map_run(&job) == -1);
}

/* Every 16-bit raw value through a block of each 16-bit type, unscaled,
 * scaled by a decimal power and by a factor, with no marker, one and two
 * (one given twice): the block loop for registers in wire order decodes
 * exactly (values bit for bit, a negative zero's sign included; ints;
 * states) what the general loop decodes from the same values byte-swapped
 * (order "BA"). */
static void test_blocks_agree(void)
{
    enum { N = 256 };
    static uint16_t wire[N], swapped[N];
    static double v1[N], v2[N];
    static int64_t i1[N], i2[N];
    static uint8_t s1[N], s2[N];
    static const int types[3] = {PYMB_MAP_U16, PYMB_MAP_I16, PYMB_MAP_SM16};
    pymb_map_marker mk[3] = {{0xFFFF, PYMB_OFFLINE}, {0x8000, PYMB_NO_SENSOR},
                             {0xFFFF, PYMB_NO_SENSOR}};
    pymb_map_out a = {v1, i1, s1, N, NULL, 0}, b = {v2, i2, s2, N, NULL, 0};
    unsigned t, scaling, nm, base, k, same = 1;

    for (t = 0; t < 3; t++) {
        for (scaling = 0; scaling < 3; scaling++) {
            for (nm = 0; nm <= 3; nm++) {
                pymb_map_entry e = entry(types[t], 1, "AB"), s;
                e.channels = N;
                e.stride = 1;
                e.nmarkers = (uint16_t)nm;
                if (scaling > 0) {
                    e.flags = PYMB_MAP_SCALED;
                    e.scale = scaling == 1 ? 0.1 : 0.5;
                    e.decimals = scaling == 1 ? 1 : 0;
                }
                s = e;
                CHECK(pymb_map_order("BA", 2, s.order) == 0);
                for (base = 0; base < 65536u; base += N) {
                    for (k = 0; k < N; k++) {
                        wire[k] = (uint16_t)(base + k);
                        swapped[k] = (uint16_t)(wire[k] << 8 | wire[k] >> 8);
                    }
                    if (pymb_map_decode(&e, 1, mk, 3, wire, N, &a) != N ||
                        pymb_map_decode(&s, 1, mk, 3, swapped, N, &b) != N ||
                        memcmp(v1, v2, sizeof v1) != 0 || memcmp(i1, i2, sizeof i1) != 0 ||
                        memcmp(s1, s2, sizeof s1) != 0) {
                        same = 0;
                    }
                }
                CHECK(same);
            }
        }
    }
}

/* A point of one channel (decode_single_16, the CoolPro's readings) decodes
 * every 16-bit raw value as the block loop does it as a channel of a block:
 * unsigned and signed, unscaled, decimal-scaled and factor-scaled, bit for
 * bit; and a single point with a marker or byte-swapped still as a block. */
static void test_singles_agree(void)
{
    enum { N = 256 };
    static uint16_t wire[N];
    static double vb[N];
    static int64_t ib[N];
    static uint8_t sb[N];
    static const int types[2] = {PYMB_MAP_U16, PYMB_MAP_I16};
    pymb_map_marker mk[1] = {{0x8000, PYMB_NO_SENSOR}};
    pymb_map_out block = {vb, ib, sb, N, NULL, 0};
    unsigned t, scaling, base, k, same = 1;

    for (t = 0; t < 2; t++) {
        for (scaling = 0; scaling < 3; scaling++) {
            pymb_map_entry e = entry(types[t], 1, "AB"), b;
            if (scaling > 0) {
                e.flags = PYMB_MAP_SCALED;
                e.scale = scaling == 1 ? 0.1 : 0.001;
                e.decimals = scaling == 1 ? 1 : 0;
            }
            b = e;
            b.channels = N;
            b.stride = 1;
            for (base = 0; base < 65536u; base += N) {
                for (k = 0; k < N; k++) {
                    wire[k] = (uint16_t)(base + k);
                }
                CHECK(pymb_map_decode(&b, 1, NULL, 0, wire, N, &block) == N);
                for (k = 0; k < N; k++) {
                    double v = -1.0;
                    int64_t i = -1;
                    uint8_t st = 0xFF;
                    pymb_map_out single = {&v, &i, &st, 1, NULL, 0};
                    e.first = k;
                    if (pymb_map_decode(&e, 1, NULL, 0, wire, N, &single) != 1 ||
                        memcmp(&v, &vb[k], sizeof v) != 0 || i != ib[k] || st != sb[k]) {
                        same = 0;
                    }
                }
            }
            CHECK(same);
        }
    }
    {   /* a marker, and a swapped register, take the block's way */
        pymb_map_entry e = entry(PYMB_MAP_U16, 1, "BA");
        double v = 0.0;
        int64_t i = 0;
        uint8_t st = 0xFF;
        pymb_map_out single = {&v, &i, &st, 1, NULL, 0};
        wire[0] = 0x0080;
        CHECK(pymb_map_decode(&e, 1, NULL, 0, wire, 1, &single) == 1 && v == 32768.0 &&
              i == 32768 && st == PYMB_VALUE);
        e = entry(PYMB_MAP_U16, 1, "AB");
        e.nmarkers = 1;
        wire[0] = 0x8000;
        CHECK(pymb_map_decode(&e, 1, mk, 1, wire, 1, &single) == 1 && isnan(v) && i == 0 &&
              st == PYMB_NO_SENSOR);
    }
}

int main(void)
{
    test_order();
    test_floats();
    test_integers();
    test_markers_blocks_strings();
    test_invalid();
    test_scale_from_masks_patterns();
    test_man_page_example();
    test_ready();
    test_blocks_agree();
    test_singles_agree();
    return check_report();
}
