/* SPDX-License-Identifier: MIT */
/*
 * pymb_master.c - a sans-I/O Modbus TCP master (see pymb_master.h): frames
 * with transaction ids (pymbi_mbap_frame), replies matched by id, checked by
 * pymb_frame.c's rules and copied into the caller's image, the rest
 * reported as events. No allocation, no I/O, no state outside the
 * caller's pymbi_master.
 */
#include <errno.h>
#include <string.h>

#include "pymb.h"
#include "pymb_master.h"

#define SLOT(m, tid) (&(m)->slots[(tid) % PYMBI_MASTER_INFLIGHT])

void pymbi_master_reset(pymbi_master *m, uint16_t tid)
{
    if (m == NULL) {
        return;
    }
    memset(m, 0, sizeof *m);
    m->next_tid = tid;
    m->oldest = tid;
}

void pymbi_master_forget(pymbi_master *m)
{
    uint32_t i;
    if (m == NULL) {
        return;
    }
    for (i = 0; i < m->span; i++) {
        pymbi_mslot *s = SLOT(m, (uint16_t)(m->oldest + i));
        s->lost = s->live;
        s->live = 0;
    }
    m->oldest = m->next_tid;
    m->span = 0;
    m->in_flight = 0;
    m->dropped = 0;
    m->drop_len = 0;
}

/* The bytes a read's data take in the image (2 a register, 2 a bit or 1 per 8
 * packed), 0: not a read. */
static uint32_t image_bytes(const pymbi_mreq *r)
{
    switch (r->function) {
    case 0x01:
    case 0x02:
        if (r->count < 1 || r->count > PYMB_MAX_READ_BITS) {
            return 0;
        }
        return r->flags & PYMBI_MREQ_PACKED ? (r->count + 7u) / 8u : 2u * r->count;
    case 0x03:
    case 0x04:
        return r->count >= 1 && r->count <= PYMB_MAX_READ_REGISTERS ? 2u * r->count : 0;
    default:
        return 0;
    }
}

static int fits(const pymbi_mreq *r, size_t image_len)
{
    uint32_t nb = image_bytes(r);
    return nb > 0 && r->offset <= image_len && nb <= image_len - r->offset;
}

/* The PDU of a read ([MB-APP] 6.1-6.4): 5 bytes. */
static void read_pdu(const pymbi_mreq *r, uint8_t pdu[5])
{
    pdu[0] = r->function;
    pdu[1] = (uint8_t)(r->address >> 8);
    pdu[2] = (uint8_t)r->address;
    pdu[3] = (uint8_t)(r->count >> 8);
    pdu[4] = (uint8_t)r->count;
}

int pymbi_master_frames(pymbi_master *m, const pymbi_mreq *reqs, size_t n, size_t image_len,
                        uint8_t *out, size_t out_cap)
{
    size_t i;
    if (m == NULL || (n > 0 && (reqs == NULL || out == NULL)) ||
        n > PYMBI_MASTER_INFLIGHT - m->span || n > out_cap / PYMBI_MASTER_FRAME) {
        errno = EINVAL;
        return -1;
    }
    for (i = 0; i < n; i++) {
        if (!fits(&reqs[i], image_len)) {
            errno = EINVAL;
            return -1;
        }
    }
    if (n > 0 && m->in_flight == 0) { /* a new wait */
        m->dropped = 0;
        m->drop_len = 0;
    }
    for (i = 0; i < n; i++) {
        const pymbi_mreq *r = &reqs[i];
        uint16_t tid = m->next_tid;
        pymbi_mslot *s = SLOT(m, tid);
        uint8_t pdu[5];

        read_pdu(r, pdu);
        pymbi_mbap_frame(tid, r->unit, pdu, sizeof pdu, out + i * PYMBI_MASTER_FRAME);
        if (m->span == 0) {
            m->oldest = tid;
        }
        s->req = *r;
        s->tid = tid;
        s->live = 1;
        s->lost = 0;
        m->span++;
        m->in_flight++;
        m->next_tid = (uint16_t)(tid + 1u);
    }
    return (int)(n * PYMBI_MASTER_FRAME);
}

/* The live slot of transaction `tid`, or NULL. */
static pymbi_mslot *in_flight(pymbi_master *m, uint16_t tid)
{
    pymbi_mslot *s;
    if ((uint16_t)(tid - m->oldest) >= m->span) {
        return NULL;
    }
    s = SLOT(m, tid);
    return s->live && s->tid == tid ? s : NULL;
}

static void release(pymbi_master *m, pymbi_mslot *s)
{
    s->live = 0;
    m->in_flight--;
    while (m->span > 0 && !SLOT(m, m->oldest)->live) {
        m->oldest = (uint16_t)(m->oldest + 1u);
        m->span--;
    }
}

static void copy_data(const pymbi_mreq *r, const uint8_t *data, uint8_t *image)
{
    uint8_t *dst = image + r->offset;
    uint32_t i;
    if (r->function >= 0x03) {
        memcpy(dst, data, 2u * r->count);
        return;
    }
    if (r->flags & PYMBI_MREQ_PACKED) {
        memcpy(dst, data, (r->count + 7u) / 8u);
        return;
    }
    for (i = 0; i < r->count; i++) { /* least significant bit first ([MB-APP] 6.1) */
        dst[2 * i] = 0;
        dst[2 * i + 1] = (uint8_t)((data[i / 8] >> (i % 8)) & 1u);
    }
}

static void note_bad(pymbi_master *m, const uint8_t *f, size_t n, int status, uint32_t token,
                     uint16_t tid, pymbi_mevent *ev)
{
    if (n > sizeof m->bad) {
        n = sizeof m->bad;
    }
    memcpy(m->bad, f, n);
    m->bad_len = n;
    m->broken = status;
    ev->kind = PYMBI_EV_BAD;
    ev->status = status;
    ev->token = token;
    ev->tid = tid;
    ev->code = 0;
}

/* One whole ADU f[0 .. n) (its MBAP length checked): 1 when it made an
 * event in *ev, else 0. */
static int take_frame(pymbi_master *m, const uint8_t *f, size_t n, uint8_t *image,
                      pymbi_mevent *ev)
{
    uint16_t tid = (uint16_t)(f[0] << 8 | f[1]);
    pymbi_mslot *s = in_flight(m, tid);
    uint8_t pdu[5];
    int status, exc = 0;

    if (s == NULL) {
        pymbi_mslot *gone = SLOT(m, tid);
        if (gone->lost && gone->tid == tid) { /* the first reply to a request given up on */
            gone->lost = 0;
            ev->kind = PYMBI_EV_LATE;
        } else { /* no answer to anything: kept for a timeout to show */
            ev->kind = PYMBI_EV_FOREIGN;
            if (m->dropped < UINT32_MAX) {
                m->dropped++;
            }
            m->drop_len = n < sizeof m->drop ? n : sizeof m->drop;
            memcpy(m->drop, f, m->drop_len);
        }
        ev->status = 0;
        ev->token = PYMBI_NO_TOKEN;
        ev->tid = tid;
        ev->code = 0;
        return 1;
    }
    read_pdu(&s->req, pdu);
    status = pymbi_tcp_check(s->req.unit, pdu, sizeof pdu, f, n, &exc);
    if (status == PYMB_FRAME_OK) {
        copy_data(&s->req, f + PYMBI_MASTER_HEAD, image);
        m->replies++;
        release(m, s);
        return 0;
    }
    if (status == PYMB_FRAME_EXCEPTION) {
        ev->kind = PYMBI_EV_EXCEPTION;
        ev->status = 0;
        ev->token = s->req.token;
        ev->tid = tid;
        ev->code = (uint8_t)exc;
        release(m, s);
        return 1;
    }
    note_bad(m, f, n, status, s->req.token, tid, ev);
    return 1;
}

int pymbi_master_take(pymbi_master *m, const uint8_t *buf, size_t len, uint8_t *image,
                      size_t image_len, pymbi_mevent *ev, size_t ev_cap, size_t *used)
{
    size_t pos = 0, nev = 0;
    uint32_t i;

    if (m == NULL || used == NULL || (buf == NULL && len > 0) || (ev == NULL && ev_cap > 0) ||
        (image == NULL && image_len > 0) || m->part_len > sizeof m->part) {
        errno = EINVAL;
        return -1;
    }
    *used = 0;
    for (i = 0; i < m->span; i++) { /* every reply in flight fits this image */
        const pymbi_mslot *s = SLOT(m, (uint16_t)(m->oldest + i));
        if (s->live && !fits(&s->req, image_len)) {
            errno = EINVAL;
            return -1;
        }
    }
    if (m->broken) {
        if (ev_cap == 0) {
            return 0;
        }
        ev[0].kind = PYMBI_EV_BAD;
        ev[0].status = m->broken;
        ev[0].token = PYMBI_NO_TOKEN;
        ev[0].tid = 0;
        ev[0].code = 0;
        return 1;
    }
    while (pos < len && nev < ev_cap) {
        size_t have = len - pos, k;
        int n;

        if (m->part_len > 0) { /* first the reply kept from the last take */
            if (m->part_len < 7) {
                k = 7 - m->part_len < have ? 7 - m->part_len : have;
                memcpy(m->part + m->part_len, buf + pos, k);
                m->part_len += k;
                pos += k;
                if (m->part_len < 7) {
                    break; /* (pos == len) */
                }
            }
            n = pymbi_mbap_length(m->part, m->part_len);
            if (n < 0) { /* shown with what follows, up to PYMBI_MASTER_HEAD bytes */
                note_bad(m, m->part, m->part_len, n, PYMBI_NO_TOKEN, 0, &ev[nev++]);
                k = PYMBI_MASTER_HEAD - m->bad_len < len - pos ? PYMBI_MASTER_HEAD - m->bad_len
                                                               : len - pos;
                memcpy(m->bad + m->bad_len, buf + pos, k);
                m->bad_len += k;
                pos += k;
                m->part_len = 0;
                break;
            }
            have = len - pos;
            k = (size_t)n - m->part_len < have ? (size_t)n - m->part_len : have;
            memcpy(m->part + m->part_len, buf + pos, k);
            m->part_len += k;
            pos += k;
            if (m->part_len < (size_t)n) {
                break; /* (pos == len) */
            }
            m->part_len = 0;
            nev += (size_t)take_frame(m, m->part, (size_t)n, image, &ev[nev]);
        } else {
            n = pymbi_mbap_length(buf + pos, have);
            if (n == PYMB_FRAME_INCOMPLETE || (n > 0 && have < (size_t)n)) {
                memcpy(m->part, buf + pos, have); /* have < n <= PYMBI_MASTER_ADU */
                m->part_len = have;
                pos = len;
                break;
            }
            if (n < 0) { /* an impossible header: nothing after it can be trusted */
                k = have < PYMBI_MASTER_HEAD ? have : PYMBI_MASTER_HEAD;
                note_bad(m, buf + pos, k, n, PYMBI_NO_TOKEN, 0, &ev[nev++]);
                pos += k;
                break;
            }
            nev += (size_t)take_frame(m, buf + pos, (size_t)n, image, &ev[nev]);
            pos += (size_t)n;
        }
        if (m->broken) {
            break;
        }
    }
    *used = pos;
    return (int)nev;
}

int pymbi_master_step(pymbi_master *m, const uint8_t *buf, size_t len, uint8_t *image,
                      size_t image_len, pymbi_mevent *ev, size_t ev_cap, size_t *used,
                      const pymbi_mreq *again, size_t n, uint8_t *out, size_t out_cap,
                      size_t *framed)
{
    int got;
    if (framed == NULL) {
        errno = EINVAL;
        return -1;
    }
    *framed = 0;
    got = pymbi_master_take(m, buf, len, image, image_len, ev, ev_cap, used);
    if (got == 0 && *used == len && n > 0 && m->in_flight == 0 && m->part_len == 0) {
        int size = pymbi_master_frames(m, again, n, image_len, out, out_cap);
        if (size > 0) {
            *framed = (size_t)size;
        }
    }
    return got;
}

int pymbi_mbap_clean(const uint8_t *buf, size_t len)
{
    size_t pos = 0;
    if (buf == NULL) {
        return len == 0;
    }
    while (pos < len) {
        size_t have = len - pos;
        int n = pymbi_mbap_length(buf + pos, have);
        if (n == PYMB_FRAME_INCOMPLETE) {
            return 1; /* too few bytes to judge yet */
        }
        if (n < 0) {
            return 0;
        }
        if (have > 7 && (buf[pos + 7] & 0x80u)) {
            return 0;
        }
        if ((size_t)n >= have) {
            return 1; /* the last reply, whole or still coming */
        }
        pos += (size_t)n;
    }
    return 1;
}

size_t pymbi_master_pending(const pymbi_master *m, uint32_t *tokens, size_t cap)
{
    size_t k = 0;
    uint32_t i;
    if (m == NULL) {
        return 0;
    }
    for (i = 0; i < m->span; i++) {
        const pymbi_mslot *s = &m->slots[(uint16_t)(m->oldest + i) % PYMBI_MASTER_INFLIGHT];
        if (s->live) {
            if (tokens != NULL && k < cap) {
                tokens[k] = s->req.token;
            }
            k++;
        }
    }
    return k;
}
