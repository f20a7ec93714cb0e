/* SPDX-License-Identifier: MIT */
/*
 * test_master.c - known-answer tests of the sans-I/O Modbus TCP master
 * (pymb_master.h): frames, replies taken whole, byte by byte, several at
 * once and out of order, exceptions, late, foreign and bad replies, bits
 * spread into words. No Python, no libmodbus.
 *
 * Source: [MB-TCP] 3.1.3 (MBAP: transaction id, protocol 0, length, unit),
 * [MB-APP] 6.1-6.4 (reads: function, address, count; the reply: function,
 * byte count, data; bits least significant first) and 7 (exceptions:
 * function | 0x80, code).
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "../pymb.h"
#include "../pymb_master.h"
#include "check.h"

static pymbi_master M; /* (large: not on the stack) */

static pymbi_mreq rq(uint8_t function, unsigned address, unsigned count, unsigned offset,
                     uint32_t token)
{
    pymbi_mreq r;
    memset(&r, 0, sizeof r);
    r.unit = 1;
    r.function = function;
    r.address = (uint16_t)address;
    r.count = (uint16_t)count;
    r.offset = offset;
    r.token = token;
    return r;
}

/* The reply to a read of `count` registers (function 3/4) with transaction
 * id `tid`: data bytes fill, fill + 1, ...; its length. */
static size_t reg_reply(uint8_t *out, unsigned tid, uint8_t function, unsigned count, uint8_t fill)
{
    size_t i, nb = 2 * count;
    out[0] = (uint8_t)(tid >> 8);
    out[1] = (uint8_t)tid;
    out[2] = 0;
    out[3] = 0;
    out[4] = (uint8_t)((3 + nb) >> 8);
    out[5] = (uint8_t)(3 + nb);
    out[6] = 1;
    out[7] = function;
    out[8] = (uint8_t)nb;
    for (i = 0; i < nb; i++) {
        out[9 + i] = (uint8_t)(fill + i);
    }
    return 9 + nb;
}

static size_t exc_reply(uint8_t *out, unsigned tid, uint8_t function, uint8_t code)
{
    const uint8_t f[9] = {(uint8_t)(tid >> 8), (uint8_t)tid, 0, 0, 0, 3, 1,
                          (uint8_t)(function | 0x80), code};
    memcpy(out, f, sizeof f);
    return sizeof f;
}

static void test_frames(void)
{
    pymbi_mreq reqs[2] = {rq(4, 0x1234, 125, 0, 7), rq(1, 5, 2000, 250, 8)};
    pymbi_mreq bad;
    uint8_t out[3 * PYMBI_MASTER_FRAME];
    const uint8_t first[PYMBI_MASTER_FRAME] = {0xFF, 0xFF, 0, 0, 0, 6, 1, 4, 0x12, 0x34, 0, 125};
    const uint8_t second[PYMBI_MASTER_FRAME] = {0, 0, 0, 0, 0, 6, 1, 1, 0, 5, 0x07, 0xD0};
    uint32_t tokens[4];

    pymbi_master_reset(&M, 0xFFFF);
    CHECK(pymbi_master_frames(&M, reqs, 2, 250 + 4000, out, sizeof out) == 24);
    CHECK(memcmp(out, first, sizeof first) == 0);
    CHECK(memcmp(out + 12, second, sizeof second) == 0); /* the id wraps to 0 */
    CHECK(M.in_flight == 2 && M.next_tid == 1 && M.dropped == 0);
    CHECK(pymbi_master_pending(&M, tokens, 4) == 2 && tokens[0] == 7 && tokens[1] == 8);
    CHECK(pymbi_master_pending(&M, tokens, 1) == 2 && tokens[0] == 7);
    /* refused, nothing held: an image too short, not a read, counts out of range */
    CHECK(pymbi_master_frames(&M, reqs, 2, 250 + 3999, out, sizeof out) == -1 &&
          errno == EINVAL && M.in_flight == 2);
    bad = rq(5, 0, 1, 0, 0);
    CHECK(pymbi_master_frames(&M, &bad, 1, 100, out, sizeof out) == -1);
    bad = rq(3, 0, 126, 0, 0);
    CHECK(pymbi_master_frames(&M, &bad, 1, 1000, out, sizeof out) == -1);
    bad = rq(3, 0, 0, 0, 0);
    CHECK(pymbi_master_frames(&M, &bad, 1, 1000, out, sizeof out) == -1);
    bad = rq(2, 0, 2001, 0, 0);
    CHECK(pymbi_master_frames(&M, &bad, 1, 10000, out, sizeof out) == -1);
    CHECK(pymbi_master_frames(&M, reqs, 2, 4250, out, 23) == -1);
    CHECK(pymbi_master_frames(NULL, reqs, 1, 4250, out, sizeof out) == -1);
    CHECK(pymbi_master_frames(&M, NULL, 1, 4250, out, sizeof out) == -1);
    CHECK(pymbi_master_frames(&M, reqs, 0, 0, NULL, 0) == 0);
    CHECK(M.in_flight == 2 && M.next_tid == 1);
    /* at most PYMBI_MASTER_INFLIGHT held */
    {
        static uint8_t big[PYMBI_MASTER_INFLIGHT * PYMBI_MASTER_FRAME];
        static pymbi_mreq many[PYMBI_MASTER_INFLIGHT];
        size_t i;
        for (i = 0; i < PYMBI_MASTER_INFLIGHT; i++) {
            many[i] = rq(3, 0, 1, 0, (uint32_t)i);
        }
        CHECK(pymbi_master_frames(&M, many, PYMBI_MASTER_INFLIGHT - 1, 2, big, sizeof big) == -1);
        CHECK(pymbi_master_frames(&M, many, PYMBI_MASTER_INFLIGHT - 2, 2, big, sizeof big) ==
              (PYMBI_MASTER_INFLIGHT - 2) * PYMBI_MASTER_FRAME);
        pymbi_master_forget(&M);
        CHECK(M.in_flight == 0 && M.span == 0);
        CHECK(pymbi_master_frames(&M, many, PYMBI_MASTER_INFLIGHT, 2, big, sizeof big) ==
              PYMBI_MASTER_INFLIGHT * PYMBI_MASTER_FRAME);
    }
}

/* Three reads, their replies in `buf` (in the order `order`), taken in
 * pieces of `step` bytes: the image and the events. */
static void test_take_in_pieces(size_t step, const int order[3])
{
    pymbi_mreq reqs[3] = {rq(4, 0, 2, 6, 0), rq(3, 10, 3, 0, 1), rq(4, 20, 1, 10, 2)};
    const unsigned counts[3] = {2, 3, 1};
    const uint8_t fns[3] = {4, 3, 4};
    uint8_t out[3 * PYMBI_MASTER_FRAME], buf[64], image[14];
    const uint8_t want[14] = {0x20, 0x21, 0x22, 0x23, 0x24, 0x25, 0x10, 0x11, 0x12, 0x13,
                              0x30, 0x31, 0xEE, 0xEE};
    const uint8_t fills[3] = {0x10, 0x20, 0x30};
    pymbi_mevent ev[4];
    size_t len = 0, pos, used;
    int i, nev = 0;

    memset(image, 0xEE, sizeof image);
    pymbi_master_reset(&M, 0xFFFE);
    CHECK(pymbi_master_frames(&M, reqs, 3, sizeof image, out, sizeof out) == 36);
    for (i = 0; i < 3; i++) {
        int k = order[i];
        len += reg_reply(buf + len, (0xFFFEu + (unsigned)k) & 0xFFFF, fns[k], counts[k], fills[k]);
    }
    for (pos = 0; pos < len; pos += used) {
        size_t n = len - pos < step ? len - pos : step;
        int got = pymbi_master_take(&M, buf + pos, n, image, sizeof image, ev, 4, &used);
        CHECK(got == 0 && used == n);
        nev += got > 0 ? got : 0;
        if (pos < len - n) {
            CHECK(M.in_flight > 0);
        }
    }
    CHECK(nev == 0 && M.in_flight == 0 && M.span == 0 && M.part_len == 0 && M.replies == 3);
    CHECK(memcmp(image, want, sizeof want) == 0);
}

static void test_take(void)
{
    static const int in_order[3] = {0, 1, 2}, reversed[3] = {2, 1, 0}, mixed[3] = {1, 2, 0};
    size_t step;
    for (step = 1; step <= 64; step++) {
        test_take_in_pieces(step, in_order);
        test_take_in_pieces(step, reversed);
        test_take_in_pieces(step, mixed);
    }
}

static void test_events(void)
{
    pymbi_mreq reqs[3] = {rq(3, 0, 1, 0, 10), rq(3, 1, 1, 2, 11), rq(3, 2, 1, 4, 12)};
    uint8_t out[3 * PYMBI_MASTER_FRAME], buf[64], image[6] = {0};
    pymbi_mevent ev[4];
    size_t len, used;
    int got;

    pymbi_master_reset(&M, 100);
    CHECK(pymbi_master_frames(&M, reqs, 3, sizeof image, out, sizeof out) == 36);
    /* an exception for 101, a foreign id (200), then 100's reply */
    len = exc_reply(buf, 101, 3, 0x02);
    len += reg_reply(buf + len, 200, 3, 1, 0x55);
    len += reg_reply(buf + len, 100, 3, 1, 0xA0);
    got = pymbi_master_take(&M, buf, len, image, sizeof image, ev, 4, &used);
    CHECK(got == 2 && used == len);
    CHECK(ev[0].kind == PYMBI_EV_EXCEPTION && ev[0].token == 11 && ev[0].code == 2 &&
          ev[0].tid == 101);
    CHECK(ev[1].kind == PYMBI_EV_FOREIGN && ev[1].tid == 200 && ev[1].token == PYMBI_NO_TOKEN);
    CHECK(image[0] == 0xA0 && image[1] == 0xA1 && M.in_flight == 1);
    /* the events array full: the take stops after the event that filled it */
    pymbi_master_forget(&M);
    len = reg_reply(buf, 102, 3, 1, 0x01);
    len += reg_reply(buf + len, 99, 3, 1, 0x01);
    got = pymbi_master_take(&M, buf, len, image, sizeof image, ev, 1, &used);
    CHECK(got == 1 && used == 11 && ev[0].kind == PYMBI_EV_LATE && ev[0].tid == 102);
    got = pymbi_master_take(&M, buf + used, len - used, image, sizeof image, ev, 1, &used);
    CHECK(got == 1 && used == 11 && ev[0].kind == PYMBI_EV_FOREIGN && ev[0].tid == 99);
    CHECK(pymbi_master_take(&M, buf, len, image, sizeof image, ev, 0, &used) == 0 && used == 0);
}

/* What a take drops: a reply to a request given up on is late (its first
 * copy, within the last PYMBI_MASTER_INFLIGHT ids); any other reply to no
 * request in flight is foreign, counted in `dropped` (restarted when a wait
 * begins) and the last kept in `drop`, for a timeout to show. */
static void test_dropped(void)
{
    pymbi_mreq reqs[2] = {rq(3, 0, 1, 0, 20), rq(3, 1, 1, 2, 21)};
    uint8_t out[PYMBI_MASTER_INFLIGHT * PYMBI_MASTER_FRAME], buf[32], other[32], image[4];
    pymbi_mevent ev[2];
    size_t len, olen, used;
    unsigned i;

    pymbi_master_reset(&M, 500);
    CHECK(pymbi_master_frames(&M, reqs, 2, sizeof image, out, sizeof out) == 24);
    olen = reg_reply(other, 0, 3, 1, 0x77); /* a device that answers under id 0 */
    CHECK(pymbi_master_take(&M, other, olen, image, sizeof image, ev, 2, &used) == 1 &&
          ev[0].kind == PYMBI_EV_FOREIGN && ev[0].tid == 0 && used == olen);
    CHECK(M.dropped == 1 && M.drop_len == olen && memcmp(M.drop, other, olen) == 0);
    len = reg_reply(buf, 500, 3, 1, 0x10); /* 500 answered: 501 still waited for */
    CHECK(pymbi_master_take(&M, buf, len, image, sizeof image, ev, 2, &used) == 0);
    CHECK(M.dropped == 1 && M.in_flight == 1);
    /* its second copy: an answer to nothing in flight */
    CHECK(pymbi_master_take(&M, buf, len, image, sizeof image, ev, 2, &used) == 1 &&
          ev[0].kind == PYMBI_EV_FOREIGN && ev[0].tid == 500);
    CHECK(M.dropped == 2 && M.drop_len == len && memcmp(M.drop, buf, len) == 0);
    /* 501 given up on: the wait is over; its reply is late, once */
    pymbi_master_forget(&M);
    CHECK(M.dropped == 0 && M.drop_len == 0);
    len = reg_reply(buf, 501, 3, 1, 0x20);
    CHECK(pymbi_master_take(&M, buf, len, image, sizeof image, ev, 2, &used) == 1 &&
          ev[0].kind == PYMBI_EV_LATE && ev[0].tid == 501 && M.dropped == 0);
    CHECK(pymbi_master_take(&M, buf, len, image, sizeof image, ev, 2, &used) == 1 &&
          ev[0].kind == PYMBI_EV_FOREIGN && M.dropped == 1);
    /* a new wait (nothing in flight): nothing dropped yet */
    CHECK(pymbi_master_frames(&M, reqs, 1, sizeof image, out, sizeof out) == 12);
    CHECK(M.dropped == 0 && M.drop_len == 0);
    /* requests framed while one is in flight: the same wait */
    CHECK(pymbi_master_take(&M, other, olen, image, sizeof image, ev, 2, &used) == 1 &&
          M.dropped == 1);
    CHECK(pymbi_master_frames(&M, reqs + 1, 1, sizeof image, out, sizeof out) == 12);
    CHECK(M.dropped == 1);

    /* given up on PYMBI_MASTER_INFLIGHT ids ago: its slot is another's */
    pymbi_master_reset(&M, 0);
    for (i = 0; i <= PYMBI_MASTER_INFLIGHT; i++) {
        CHECK(pymbi_master_frames(&M, reqs, 1, sizeof image, out, sizeof out) == 12);
        pymbi_master_forget(&M);
    }
    len = reg_reply(buf, 0, 3, 1, 0x30);
    CHECK(pymbi_master_take(&M, buf, len, image, sizeof image, ev, 2, &used) == 1 &&
          ev[0].kind == PYMBI_EV_FOREIGN);
    len = reg_reply(buf, 1, 3, 1, 0x30);
    CHECK(pymbi_master_take(&M, buf, len, image, sizeof image, ev, 2, &used) == 1 &&
          ev[0].kind == PYMBI_EV_LATE);
}

/* A frame that answers a request in flight but is no answer to it: one BAD
 * event with `status`, repeated until the reset. */
static void check_bad(const uint8_t *frame, size_t n, int status, uint32_t token)
{
    pymbi_mreq r = rq(3, 7, 2, 0, 42);
    uint8_t out[PYMBI_MASTER_FRAME], image[4];
    pymbi_mevent ev[2];
    size_t used;

    pymbi_master_reset(&M, 0x0102);
    CHECK(pymbi_master_frames(&M, &r, 1, sizeof image, out, sizeof out) == 12);
    CHECK(pymbi_master_take(&M, frame, n, image, sizeof image, ev, 2, &used) == 1);
    CHECK(ev[0].kind == PYMBI_EV_BAD && ev[0].status == status && ev[0].token == token);
    CHECK(M.bad_len > 0 && M.bad_len <= n && memcmp(M.bad, frame, M.bad_len) == 0);
    CHECK(pymbi_master_take(&M, frame, n, image, sizeof image, ev, 2, &used) == 1 &&
          ev[0].kind == PYMBI_EV_BAD && used == 0);
    pymbi_master_reset(&M, 0);
    CHECK(M.broken == 0 && M.in_flight == 0);
}

static void test_bad(void)
{
    /* another unit */
    const uint8_t unit[] = {1, 2, 0, 0, 0, 7, 9, 3, 4, 0, 1, 0, 2};
    /* a byte count that is not the count asked for */
    const uint8_t count[] = {1, 2, 0, 0, 0, 5, 1, 3, 2, 0, 1};
    /* another function */
    const uint8_t fn[] = {1, 2, 0, 0, 0, 7, 1, 4, 4, 0, 1, 0, 2};
    /* an MBAP length of 2 (no data): the request path's rule, a bad length */
    const uint8_t two[] = {1, 2, 0, 0, 0, 2, 1, 3};
    /* protocol 1; a length of 255; a length of 1 */
    const uint8_t proto[] = {1, 2, 0, 1, 0, 7, 1, 3, 4, 0, 1, 0, 2};
    const uint8_t long_[] = {1, 2, 0, 0, 0, 255, 1};
    const uint8_t one[] = {1, 2, 0, 0, 0, 1, 1};
    /* an exception reply with a byte too many */
    const uint8_t exc[] = {1, 2, 0, 0, 0, 4, 1, 0x83, 2, 0};

    check_bad(unit, sizeof unit, PYMB_FRAME_BAD_SLAVE, 42);
    check_bad(count, sizeof count, PYMB_FRAME_BAD_LENGTH, 42);
    check_bad(fn, sizeof fn, PYMB_FRAME_BAD_FUNCTION, 42);
    check_bad(two, sizeof two, PYMB_FRAME_BAD_LENGTH, 42);
    check_bad(proto, sizeof proto, PYMB_FRAME_BAD_HEADER, PYMBI_NO_TOKEN);
    check_bad(long_, sizeof long_, PYMB_FRAME_BAD_HEADER, PYMBI_NO_TOKEN);
    check_bad(one, sizeof one, PYMB_FRAME_BAD_HEADER, PYMBI_NO_TOKEN);
    check_bad(exc, sizeof exc, PYMB_FRAME_BAD_LENGTH, 42);
    /* the one length rule: 2..254 */
    CHECK(pymbi_mbap_length(two, sizeof two) == 8);
    CHECK(pymbi_mbap_length(one, sizeof one) == PYMB_FRAME_BAD_HEADER);
    CHECK(pymbi_mbap_length(long_, sizeof long_) == PYMB_FRAME_BAD_HEADER);
    CHECK(pymbi_mbap_length(unit, 6) == 13); /* judged as soon as its bytes are in */
    CHECK(pymbi_mbap_length(unit, 5) == PYMB_FRAME_INCOMPLETE);
    CHECK(pymbi_mbap_length(proto, 4) == PYMB_FRAME_BAD_HEADER);
    CHECK(pymbi_mbap_length(proto, 3) == PYMB_FRAME_INCOMPLETE);
    CHECK(pymbi_mbap_length(NULL, 7) == PYMB_FRAME_INCOMPLETE);
    {
        const uint8_t most[] = {0, 0, 0, 0, 0, 254, 1};
        CHECK(pymbi_mbap_length(most, sizeof most) == 260);
    }
    /* the one TCP reply check: unit, then the PDU against the request's */
    {
        const uint8_t req[5] = {3, 0, 1, 0, 2};
        const uint8_t ok[] = {1, 2, 0, 0, 0, 7, 1, 3, 4, 0, 1, 0, 2};
        const uint8_t refused[] = {1, 2, 0, 0, 0, 3, 1, 0x83, 0x0B};
        int code = 0;
        CHECK(pymbi_tcp_check(1, req, sizeof req, ok, sizeof ok, &code) == PYMB_FRAME_OK);
        CHECK(pymbi_tcp_check(9, req, sizeof req, unit, sizeof unit, &code) == PYMB_FRAME_OK);
        CHECK(pymbi_tcp_check(1, req, sizeof req, unit, sizeof unit, &code) ==
              PYMB_FRAME_BAD_SLAVE);
        CHECK(pymbi_tcp_check(1, req, sizeof req, refused, sizeof refused, &code) ==
                  PYMB_FRAME_EXCEPTION &&
              code == 0x0B);
        CHECK(pymbi_tcp_check(1, req, sizeof req, ok, 6, &code) == PYMB_FRAME_BAD_LENGTH);
        CHECK(pymbi_tcp_check(1, NULL, 0, ok, sizeof ok, &code) == PYMB_FRAME_INVALID);
        CHECK(pymbi_tcp_check(1, req, sizeof req, NULL, 0, &code) == PYMB_FRAME_INVALID);
    }
}

static void test_bits(void)
{
    pymbi_mreq r = rq(1, 0, 10, 2, 5);
    uint8_t out[PYMBI_MASTER_FRAME], image[24];
    /* 10 coils: 1,0,1,1,0,0,0,0 | 1,1 */
    const uint8_t rsp[] = {0, 1, 0, 0, 0, 5, 1, 1, 2, 0x0D, 0x03};
    const uint8_t want[] = {0xEE, 0xEE, 0, 1, 0, 0, 0, 1, 0, 1, 0, 0, 0, 0,
                            0, 0, 0, 0, 0, 1, 0, 1, 0xEE, 0xEE};
    pymbi_mevent ev[1];
    size_t used;

    memset(image, 0xEE, sizeof image);
    pymbi_master_reset(&M, 1);
    CHECK(pymbi_master_frames(&M, &r, 1, sizeof image - 2, out, sizeof out) == 12);
    CHECK(pymbi_master_take(&M, rsp, sizeof rsp, image, sizeof image, ev, 1, &used) == 0 &&
          used == sizeof rsp && M.in_flight == 0);
    CHECK(memcmp(image, want, sizeof want) == 0);
    /* packed: the reply's bytes as they come, (10 + 7) / 8 of them */
    memset(image, 0xEE, sizeof image);
    r.flags = PYMBI_MREQ_PACKED;
    r.offset = 21;
    pymbi_master_reset(&M, 1);
    CHECK(pymbi_master_frames(&M, &r, 1, 22, out, sizeof out) == -1);
    CHECK(pymbi_master_frames(&M, &r, 1, 23, out, sizeof out) == 12);
    CHECK(pymbi_master_take(&M, rsp, sizeof rsp, image, 23, ev, 1, &used) == 0 &&
          M.in_flight == 0);
    CHECK(image[20] == 0xEE && image[21] == 0x0D && image[22] == 0x03 && image[23] == 0xEE);
}

static void test_args(void)
{
    pymbi_mreq r = rq(3, 0, 4, 0, 1);
    uint8_t out[PYMBI_MASTER_FRAME], image[8], buf[1] = {0};
    pymbi_mevent ev[1];
    size_t used = 99;

    pymbi_master_reset(&M, 0);
    CHECK(pymbi_master_frames(&M, &r, 1, sizeof image, out, sizeof out) == 12);
    /* an image shorter than the one the request was framed for */
    CHECK(pymbi_master_take(&M, buf, 1, image, sizeof image - 1, ev, 1, &used) == -1 &&
          errno == EINVAL);
    CHECK(pymbi_master_take(&M, NULL, 1, image, sizeof image, ev, 1, &used) == -1);
    CHECK(pymbi_master_take(&M, buf, 1, image, sizeof image, NULL, 1, &used) == -1);
    CHECK(pymbi_master_take(&M, buf, 1, image, sizeof image, ev, 1, NULL) == -1);
    CHECK(pymbi_master_take(NULL, buf, 1, image, sizeof image, ev, 1, &used) == -1);
    CHECK(pymbi_master_take(&M, NULL, 0, image, sizeof image, ev, 1, &used) == 0 && used == 0);
    CHECK(pymbi_master_pending(NULL, NULL, 0) == 0);
    CHECK(pymbi_master_pending(&M, NULL, 0) == 1);
    pymbi_master_reset(NULL, 0);
    pymbi_master_forget(NULL);
}

/* A step: the poll's last reply taken, the next poll framed at once; not
 * framed while a reply is missing or cut short, after an event, or with
 * nothing to frame. */
static void test_step(void)
{
    pymbi_mreq reqs[2] = {rq(4, 0, 2, 0, 0), rq(3, 10, 1, 4, 1)};
    uint8_t out[2 * PYMBI_MASTER_FRAME], buf[64], image[6];
    pymbi_mevent ev[2];
    size_t len, used, framed = 99;
    int i;

    pymbi_master_reset(&M, 7);
    CHECK(pymbi_master_frames(&M, reqs, 2, sizeof image, out, sizeof out) == 24);
    len = reg_reply(buf, 7, 4, 2, 0x10);
    /* the first reply alone: one still in flight, nothing framed */
    CHECK(pymbi_master_step(&M, buf, len, image, sizeof image, ev, 2, &used, reqs, 2, out,
                            sizeof out, &framed) == 0);
    CHECK(used == len && framed == 0 && M.in_flight == 1);
    /* the second one in two pieces: cut short first (not framed), then whole */
    len = reg_reply(buf, 8, 3, 1, 0x20);
    CHECK(pymbi_master_step(&M, buf, 5, image, sizeof image, ev, 2, &used, reqs, 2, out,
                            sizeof out, &framed) == 0);
    CHECK(used == 5 && framed == 0 && M.part_len == 5);
    memset(out, 0, sizeof out);
    CHECK(pymbi_master_step(&M, buf + 5, len - 5, image, sizeof image, ev, 2, &used, reqs, 2,
                            out, sizeof out, &framed) == 0);
    CHECK(used == len - 5 && framed == 24 && M.in_flight == 2 && M.replies == 2);
    CHECK(image[0] == 0x10 && image[3] == 0x13 && image[4] == 0x20 && image[5] == 0x21);
    /* the next poll: ids 9 and 10, as pymbi_master_frames writes them */
    CHECK(out[0] == 0 && out[1] == 9 && out[7] == 4 && out[12] == 0 && out[13] == 10 &&
          out[19] == 3 && out[21] == 10);
    /* an exception ends the poll: an event, nothing framed */
    len = exc_reply(buf, 9, 4, 0x02);
    len += reg_reply(buf + len, 10, 3, 1, 0x30);
    CHECK(pymbi_master_step(&M, buf, len, image, sizeof image, ev, 2, &used, reqs, 2, out,
                            sizeof out, &framed) == 1);
    CHECK(ev[0].kind == PYMBI_EV_EXCEPTION && framed == 0 && M.in_flight == 0);
    /* nothing to frame, no room for the frames: not framed */
    for (i = 0; i < 2; i++) {
        size_t cap = i == 0 ? sizeof out : PYMBI_MASTER_FRAME;
        size_t n = i == 0 ? 0 : 2;
        pymbi_master_reset(&M, 1);
        CHECK(pymbi_master_frames(&M, reqs, 1, sizeof image, out, sizeof out) == 12);
        len = reg_reply(buf, 1, 4, 2, 0x40);
        CHECK(pymbi_master_step(&M, buf, len, image, sizeof image, ev, 2, &used, reqs, n, out,
                                cap, &framed) == 0);
        CHECK(framed == 0 && M.in_flight == 0 && M.replies == 1);
    }
    CHECK(pymbi_master_step(&M, buf, len, image, sizeof image, ev, 2, &used, reqs, 1, out,
                            sizeof out, NULL) == -1 && errno == EINVAL);
}

static void test_clean(void)
{
    uint8_t buf[64];
    size_t n = reg_reply(buf, 1, 0x03, 2, 0);
    CHECK(pymbi_mbap_clean(buf, 0) == 1);
    CHECK(pymbi_mbap_clean(NULL, 0) == 1 && pymbi_mbap_clean(NULL, 3) == 0);
    CHECK(pymbi_mbap_clean(buf, 3) == 1); /* too few bytes to judge */
    CHECK(pymbi_mbap_clean(buf, 8) == 1); /* a reply still coming */
    CHECK(pymbi_mbap_clean(buf, n) == 1);
    n += exc_reply(buf + n, 2, 0x03, 2);
    CHECK(pymbi_mbap_clean(buf, n - 2) == 1); /* its function byte not yet in */
    CHECK(pymbi_mbap_clean(buf, n - 1) == 0); /* an exception */
    CHECK(pymbi_mbap_clean(buf, n) == 0);
    buf[13 + 2] = 1; /* the second reply's protocol id: an impossible header */
    buf[13 + 7] = 0x03;
    CHECK(pymbi_mbap_clean(buf, 13 + 6) == 0);
}

int main(void)
{
    test_clean();
    test_frames();
    test_take();
    test_events();
    test_dropped();
    test_bad();
    test_bits();
    test_args();
    test_step();
    return check_report();
}
