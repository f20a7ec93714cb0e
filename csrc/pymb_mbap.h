/* SPDX-License-Identifier: MIT */
/*
 * pymb_mbap.h - the requests and replies of a pipelined Modbus TCP poll, a
 * whole poll's worth in one call (the one-loop TCP poller of pymb log,
 * pymb.logger.tcploop). Not installed and not in libpymb: the Python
 * extension compiles pymb_mbap.c beside the core; names are pymbi_*.
 *
 * A poll is a table of read requests made ready once (pymbi_mbap_req): the
 * request after its transaction id, its reply's first 9 bytes after the
 * transaction id, the reply's size and where its data bytes go in the
 * poll's register image (big-endian, as on the wire and as the store keeps
 * them). pymbi_mbap_frames() writes some of them with consecutive
 * transaction ids; pymbi_mbap_take() checks the replies that came, in the
 * order they were sent, and copies their data bytes into the image. Anything
 * else (another transaction id, an exception, a reply in another order) is
 * left where it is for the caller's own checks. Needs only the C99 library.
 *
 * Documents cited:
 *   [MB-TCP] Modbus Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3 (MBAP)
 *   [MB-APP] Modbus Application Protocol V1.1b3, 6.1-6.4 (read requests)
 */
#ifndef PYMB_MBAP_H
#define PYMB_MBAP_H

#include <stddef.h>
#include <stdint.h>

#define PYMBI_MBAP_FRAME 12 /* a read request: MBAP (7) + function, address, count */
#define PYMBI_MBAP_HEAD 9   /* a read reply's MBAP, function code and byte count */

typedef struct {
    uint8_t tail[10];  /* the request after its transaction id ([MB-TCP] 3.1.3) */
    uint8_t head[7];   /* its reply's first 9 bytes after the transaction id */
    uint16_t size;     /* the reply's bytes: PYMBI_MBAP_HEAD + its data bytes */
    uint32_t offset;   /* where the data bytes go in the image */
} pymbi_mbap_req;

/* Write the frames of reqs[first .. first + n) to out, PYMBI_MBAP_FRAME
 * bytes each, with transaction ids tid, tid + 1, ... (modulo 65536).
 * Returns the bytes written; -1 (errno EINVAL) when first + n exceeds nreqs
 * or out_cap is too small. */
int pymbi_mbap_frames(const pymbi_mbap_req *reqs, size_t nreqs, size_t first, size_t n,
                      uint16_t tid, uint8_t *out, size_t out_cap);

/* Take from buf[0 .. len) the replies to reqs[first .. first + n), sent with
 * transaction ids tid, tid + 1, ..., in that order: each whole reply whose
 * first 9 bytes are the expected ones has its data bytes copied to
 * image[offset ..]. Stops before the first reply that is not the next one
 * whole (another transaction id, an exception, a reply cut short).
 * Returns the replies taken (0 .. n) and sets *used to the bytes they took;
 * -1 (errno EINVAL) when first + n exceeds nreqs or a request's data would
 * not fit in the image (nothing is copied then). */
int pymbi_mbap_take(const pymbi_mbap_req *reqs, size_t nreqs, size_t first, size_t n,
                    uint16_t tid, const uint8_t *buf, size_t len, uint8_t *image,
                    size_t image_len, size_t *used);

#endif
