/* SPDX-License-Identifier: MIT */
/*
 * pymb_master.h - a sans-I/O Modbus TCP master: a poll's read requests
 * framed with transaction ids, the bytes that come back taken as they come
 * (a part of a reply, several at once, in another order), each reply matched
 * to its request by its transaction id, checked with the request path's
 * rules (pymbi_mbap_length and pymb_check_response_pdu, pymb_frame.c) and its
 * data copied into the poll's register image. What is not a reply to a
 * request in flight is an event the caller reads: an exception (a refused
 * request), a late reply (to a request no longer in flight), a foreign one
 * (to an id never sent), a bad frame (the stream is out of step).
 *
 * Not installed; the names are pymbi_* (the version script exports pymb_*
 * only). No I/O, no allocation, no state but the pymbi_master the caller
 * owns; every length is checked. Needs only the C99 library and pymb_frame.c.
 * Users: pymb log's one TCP loop and pymb bench's bare loop (through
 * pymb._native.master); the request path's Modbus TCP transport (one request
 * at a time) matches its own replies, and frames and checks them with the
 * same three rules (pymbi_mbap_frame, pymbi_mbap_length, pymbi_tcp_check).
 *
 * Documents cited:
 *   [MB-TCP] Modbus Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3 (MBAP)
 *   [MB-APP] Modbus Application Protocol V1.1b3, 6.1-6.4 (read requests), 7 (exceptions)
 */
#ifndef PYMB_MASTER_H
#define PYMB_MASTER_H

#include <stddef.h>
#include <stdint.h>

#define PYMBI_MASTER_FRAME 12     /* a read request: MBAP (7) + function, address, count */
#define PYMBI_MASTER_HEAD 9       /* a read reply's MBAP, function code and byte count */
#define PYMBI_MASTER_ADU 260      /* the longest ADU: 6 + the longest MBAP length (254) */
#define PYMBI_MASTER_INFLIGHT 256 /* the most requests in flight at once */

/*
 * [MB-TCP] 3.1.3: the whole ADU's length from its first `have` bytes: 6 + the
 * MBAP length, which counts the unit id and the PDU (2 .. 1 + 253). A
 * negative pymb_frame_status: PYMB_FRAME_BAD_HEADER (a protocol id other
 * than 0, said from 4 bytes on; a length out of range, from 6 on), else
 * PYMB_FRAME_INCOMPLETE (fewer than 6 bytes). The one MBAP length rule (the
 * request path's TCP and UDP transports and pymb serve's requests use it too).
 */
int pymbi_mbap_length(const uint8_t *adu, size_t have);

/*
 * [MB-TCP] 3.1.3: the ADU of pdu[0 .. pdu_len) (1 .. 253 bytes, which may
 * already stand at adu + 7) for `unit` under transaction id tid into adu
 * (pdu_len + 7 bytes): its length. The one MBAP framing (the request path's
 * TCP and UDP transports and pymb serve's replies use it too).
 */
int pymbi_mbap_frame(uint16_t tid, uint8_t unit, const uint8_t *pdu, size_t pdu_len,
                     uint8_t *adu);

/*
 * A Modbus TCP reply ADU adu[0 .. n) (its MBAP length checked) against the
 * request it answers: its unit id and its PDU req_pdu[0 .. req_len). A
 * pymb_frame_status: PYMB_FRAME_BAD_SLAVE (another unit), or what
 * pymb_check_response_pdu says (*exception_code for an exception). The one
 * TCP reply check (the request path's TCP transport uses it too).
 */
int pymbi_tcp_check(uint8_t unit, const uint8_t *req_pdu, size_t req_len, const uint8_t *adu,
                    size_t n, int *exception_code);

/* One read request of a poll ([MB-APP] 6.1-6.4). */
typedef struct {
    uint32_t offset;   /* where its data go in the image, in bytes */
    uint32_t token;    /* the caller's name for it (events and pymbi_master_pending say it) */
    uint16_t address;
    uint16_t count;    /* 1..125 registers (functions 3, 4), 1..2000 bits (1, 2) */
    uint8_t unit;
    uint8_t function;  /* 1, 2: each bit as a big-endian 0/1 word (2 bytes) in the image
                          (PYMBI_MREQ_PACKED: the reply's (count + 7) / 8 bytes as they
                          come); 3, 4: the registers as they come (big-endian) */
    uint8_t flags;     /* 0 or PYMBI_MREQ_PACKED */
} pymbi_mreq;

#define PYMBI_MREQ_PACKED 1 /* a read of bits: its data bytes as the reply packs them */

typedef enum {
    PYMBI_EV_EXCEPTION = 1, /* the request `token` was refused: exception `code` */
    PYMBI_EV_LATE = 2,      /* a reply to id `tid`, a request given up on (pymbi_master_forget
                               while in flight; one of the last PYMBI_MASTER_INFLIGHT sent),
                               its first reply */
    PYMBI_EV_FOREIGN = 3,   /* a reply to id `tid`, no request in flight nor given up on (never
                               sent, answered already, or a device that answers under another
                               id): counted in `dropped`, the last kept in `drop` */
    PYMBI_EV_BAD = 4        /* a frame that is no answer (`status`): the stream is out of
                               step; the frame is m->bad[0 .. bad_len), `token` the request
                               its id matched (PYMBI_NO_TOKEN: none) */
} pymbi_event_kind;

#define PYMBI_NO_TOKEN 0xFFFFFFFFu

typedef struct {
    int kind;       /* a pymbi_event_kind */
    int status;     /* PYMBI_EV_BAD: a pymb_frame_status; else 0 */
    uint32_t token; /* the request concerned, PYMBI_NO_TOKEN: none */
    uint16_t tid;   /* the frame's transaction id (PYMBI_EV_BAD: 0 if the header was bad) */
    uint8_t code;   /* PYMBI_EV_EXCEPTION: the exception code */
} pymbi_mevent;

typedef struct {
    pymbi_mreq req;
    uint16_t tid;
    uint8_t live;
    uint8_t lost; /* given up on while in flight (pymbi_master_forget): a reply is late */
} pymbi_mslot;

/* A stream's master; the caller owns it (reset before use, on each new
 * connection). The fields are read-only to the caller. */
typedef struct {
    uint16_t next_tid;      /* the id the next request gets */
    uint16_t oldest;        /* the id of the oldest request whose slot is still held */
    uint32_t span;          /* slots held: ids oldest .. oldest + span - 1 */
    uint32_t in_flight;     /* of those, requests still waiting for their reply */
    uint32_t dropped;       /* PYMBI_EV_FOREIGN replies since the wait began (requests framed
                               with none in flight, pymbi_master_forget, the reset): a
                               timeout says the device answered, under another id */
    uint64_t replies;       /* replies taken into an image since the reset */
    int broken;             /* a bad frame was seen: take refuses until the reset */
    size_t part_len;        /* a reply's first bytes, kept for the next take */
    uint8_t part[PYMBI_MASTER_ADU];
    size_t bad_len;         /* the last bad frame (or its first bytes) */
    uint8_t bad[PYMBI_MASTER_ADU];
    size_t drop_len;        /* the last of the `dropped` replies (only those are copied) */
    uint8_t drop[PYMBI_MASTER_ADU];
    pymbi_mslot slots[PYMBI_MASTER_INFLIGHT];
} pymbi_master;

/* A new stream: nothing in flight, nothing kept; the first request gets
 * transaction id `tid`. */
void pymbi_master_reset(pymbi_master *m, uint16_t tid);

/* Nothing is in flight any more: replies still on their way are late (the
 * first reply to each; the wait is over: `dropped` restarts). */
void pymbi_master_forget(pymbi_master *m);

/* Frame reqs[0 .. n) into out (PYMBI_MASTER_FRAME bytes each) with the next
 * transaction ids, and hold them in flight. Returns the bytes written; -1
 * (errno EINVAL) when a request is not a valid read, its data would not fit
 * an image of image_len bytes, out_cap is too small, or more than
 * PYMBI_MASTER_INFLIGHT would be held; nothing is sent or held then. With
 * nothing in flight before, a wait begins: `dropped` restarts. */
int pymbi_master_frames(pymbi_master *m, const pymbi_mreq *reqs, size_t n, size_t image_len,
                        uint8_t *out, size_t out_cap);

/* Take buf[0 .. len): each reply to a request in flight is checked and, if
 * it is the read's answer, its data copied into image (which must be as
 * long as the image_len the request was framed for); anything else is an
 * event in ev[0 .. ev_cap). A reply cut short is kept for the next take.
 * Returns the events written and sets *used to the bytes taken (all of
 * them, unless ev filled up or a PYMBI_EV_BAD event ended the take: the
 * stream is then out of step, and later takes only report it again until
 * pymbi_master_reset). -1 (errno EINVAL) on invalid arguments. */
int pymbi_master_take(pymbi_master *m, const uint8_t *buf, size_t len, uint8_t *image,
                      size_t image_len, pymbi_mevent *ev, size_t ev_cap, size_t *used);

/* pymbi_master_take, and when that take ended the poll (no event, every byte
 * used, nothing in flight, nothing kept) and `again` has n > 0 reads: frames
 * them, reads of the same image, into out as pymbi_master_frames does (the
 * next poll, under way from then on) and says their bytes in *framed; else
 * *framed is 0 (not framed: also when pymbi_master_frames refuses them).
 * Returns what the take returned (-1 with EINVAL also for a NULL framed). */
int pymbi_master_step(pymbi_master *m, const uint8_t *buf, size_t len, uint8_t *image,
                      size_t image_len, pymbi_mevent *ev, size_t ev_cap, size_t *used,
                      const pymbi_mreq *again, size_t n, uint8_t *out, size_t out_cap,
                      size_t *framed);

/* Whether buf[0 .. len), the first bytes of a stream of Modbus TCP replies,
 * holds only replies that are no exception ([MB-APP] 7: function | 0x80) and
 * a valid header: 1 when every whole reply is one and the last, cut short,
 * has a valid MBAP header so far and no exception function (or not yet its
 * function byte); 0 for an exception or an impossible header. A poll whose
 * replies are slow (not all in) but so far clean is only slow: the TCP loop
 * keeps waiting for all of them at once (pymb_loop.h). */
int pymbi_mbap_clean(const uint8_t *buf, size_t len);

/* The tokens of the requests in flight, oldest first, into tokens[0 .. cap):
 * how many there are (more than cap: only cap written). */
size_t pymbi_master_pending(const pymbi_master *m, uint32_t *tokens, size_t cap);

#endif
