/* SPDX-License-Identifier: MIT */
/*
 * test_mbap.c - known-answer tests of a pipelined Modbus TCP poll's frames
 * and replies (pymbi_mbap_frames, pymbi_mbap_take): no Python, no libmodbus.
 *
 * Source: [MB-TCP] 3.1.3 (MBAP: transaction id, protocol 0, length, unit)
 * and [MB-APP] 6.4 (read input registers: function 4, address, count; the
 * reply: function, byte count, 2 bytes a register, big-endian).
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "../pymb_mbap.h"
#include "check.h"

/* A read of `count` input registers at `address` from unit 1 whose data go
 * to `offset` in the image. */
static pymbi_mbap_req req(unsigned address, unsigned count, unsigned offset)
{
    pymbi_mbap_req r;
    unsigned nbytes = 2 * count;
    memset(&r, 0, sizeof r);
    /* protocol 0, length 6, unit 1, function 4, address, count */
    r.tail[2] = 0;
    r.tail[3] = 6;
    r.tail[4] = 1;
    r.tail[5] = 4;
    r.tail[6] = (uint8_t)(address >> 8);
    r.tail[7] = (uint8_t)address;
    r.tail[8] = (uint8_t)(count >> 8);
    r.tail[9] = (uint8_t)count;
    /* protocol 0, length 3 + bytes, unit 1, function 4, byte count */
    r.head[2] = 0;
    r.head[3] = (uint8_t)(3 + nbytes);
    r.head[4] = 1;
    r.head[5] = 4;
    r.head[6] = (uint8_t)nbytes;
    r.size = (uint16_t)(PYMBI_MBAP_HEAD + nbytes);
    r.offset = offset;
    return r;
}

/* The reply to `r` sent with transaction id `tid`, its data bytes `fill`,
 * fill + 1, ...; returns its length. */
static size_t reply(const pymbi_mbap_req *r, unsigned tid, uint8_t fill, uint8_t *out)
{
    size_t i;
    out[0] = (uint8_t)(tid >> 8);
    out[1] = (uint8_t)tid;
    memcpy(out + 2, r->head, sizeof r->head);
    for (i = PYMBI_MBAP_HEAD; i < r->size; i++)
        out[i] = (uint8_t)(fill + i - PYMBI_MBAP_HEAD);
    return r->size;
}

static void test_frames(void)
{
    pymbi_mbap_req reqs[3] = {req(0, 2, 0), req(0x1234, 125, 4), req(100, 1, 254)};
    uint8_t out[3 * PYMBI_MBAP_FRAME];
    static const uint8_t want[] = {
        0xFF, 0xFF, 0, 0, 0, 6, 1, 4, 0x12, 0x34, 0, 125, /* tid 65535 */
        0x00, 0x00, 0, 0, 0, 6, 1, 4, 0x00, 0x64, 0, 1,   /* tid 0: wrapped */
    };
    CHECK(pymbi_mbap_frames(reqs, 3, 1, 2, 0xFFFF, out, sizeof out) == 24);
    CHECK(memcmp(out, want, sizeof want) == 0);
    CHECK(pymbi_mbap_frames(reqs, 3, 0, 0, 7, out, 0) == 0);
    errno = 0;
    CHECK(pymbi_mbap_frames(reqs, 3, 2, 2, 1, out, sizeof out) == -1 && errno == EINVAL);
    errno = 0;
    CHECK(pymbi_mbap_frames(reqs, 3, 4, 0, 1, out, sizeof out) == -1 && errno == EINVAL);
    errno = 0;
    CHECK(pymbi_mbap_frames(reqs, 3, 0, 3, 1, out, sizeof out - 1) == -1 && errno == EINVAL);
    errno = 0;
    CHECK(pymbi_mbap_frames(NULL, 3, 0, 1, 1, out, sizeof out) == -1 && errno == EINVAL);
}

static void test_take(void)
{
    pymbi_mbap_req reqs[3] = {req(0, 2, 6), req(10, 3, 0), req(20, 1, 10)};
    uint8_t buf[64], image[12];
    size_t len = 0, used = 99;
    static const uint8_t want[12] = {0x20, 0x21, 0x22, 0x23, 0x24, 0x25,
                                     0x10, 0x11, 0x12, 0x13, 0x30, 0x31};
    len += reply(&reqs[0], 0xFFFE, 0x10, buf + len);
    len += reply(&reqs[1], 0xFFFF, 0x20, buf + len);
    len += reply(&reqs[2], 0x0000, 0x30, buf + len);
    memset(image, 0, sizeof image);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, buf, len, image, sizeof image, &used) == 3);
    CHECK(used == len);
    CHECK(memcmp(image, want, sizeof image) == 0);

    /* a reply cut short: the whole ones before it are taken, it is left */
    memset(image, 0, sizeof image);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, buf, len - 1, image, sizeof image,
                          &used) == 2);
    CHECK(used == reqs[0].size + reqs[1].size);
    CHECK(image[10] == 0 && image[11] == 0 && image[0] == 0x20);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, buf, 5, image, sizeof image, &used) == 0);
    CHECK(used == 0);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, buf, 0, image, sizeof image, &used) == 0);

    /* starting further in the table, with fewer expected than came */
    CHECK(pymbi_mbap_take(reqs, 3, 1, 1, 0xFFFF, buf + reqs[0].size, len - reqs[0].size,
                          image, sizeof image, &used) == 1);
    CHECK(used == reqs[1].size);

    /* another transaction id, an exception, another unit, another byte count: left */
    {
        uint8_t other[64];
        memcpy(other, buf, len);
        other[1] ^= 1; /* tid */
        CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, other, len, image, sizeof image,
                              &used) == 0 && used == 0);
        memcpy(other, buf, len);
        other[reqs[0].size + 7] = 0x84; /* exception to the second request */
        CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, other, len, image, sizeof image,
                              &used) == 1 && used == reqs[0].size);
        memcpy(other, buf, len);
        other[6] = 2; /* unit */
        CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, other, len, image, sizeof image,
                              &used) == 0);
        memcpy(other, buf, len);
        other[8] = 6; /* byte count */
        CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, other, len, image, sizeof image,
                              &used) == 0);
        /* replies in another order: the first is not the expected one */
        len = reply(&reqs[1], 0xFFFF, 0x20, other);
        len += reply(&reqs[0], 0xFFFE, 0x10, other + len);
        CHECK(pymbi_mbap_take(reqs, 3, 0, 2, 0xFFFE, other, len, image, sizeof image,
                              &used) == 0);
    }

    /* a table that does not fit the image, or a range past the table: nothing copied */
    memset(image, 0, sizeof image);
    errno = 0;
    CHECK(pymbi_mbap_take(reqs, 3, 0, 3, 0xFFFE, buf, len, image, sizeof image - 1,
                          &used) == -1 && errno == EINVAL);
    {
        pymbi_mbap_req bad[2] = {req(0, 2, 0), req(0, 1, 0)};
        bad[1].size = 3; /* shorter than a head */
        errno = 0;
        CHECK(pymbi_mbap_take(bad, 2, 0, 2, 0, buf, len, image, sizeof image, &used) == -1 &&
              errno == EINVAL);
        bad[1] = req(0, 1, 0xFFFFFFFFu); /* an offset past any image */
        CHECK(pymbi_mbap_take(bad, 2, 0, 2, 0, buf, len, image, sizeof image, &used) == -1);
    }
    CHECK(image[0] == 0);
    CHECK(pymbi_mbap_take(reqs, 3, 2, 2, 0, buf, len, image, sizeof image, &used) == -1);
    CHECK(pymbi_mbap_take(reqs, 3, 4, 0, 0, buf, len, image, sizeof image, &used) == -1);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 1, 0, NULL, 5, image, sizeof image, &used) == -1);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 1, 0, buf, len, image, sizeof image, NULL) == -1);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 1, 0, buf, len, NULL, 0, &used) == -1);
    CHECK(pymbi_mbap_take(reqs, 3, 0, 0, 0, NULL, 0, NULL, 0, &used) == 0 && used == 0);
}

int main(void)
{
    test_frames();
    test_take();
    return check_report();
}
