/* SPDX-License-Identifier: MIT */
/*
 * pymb_loop.c - the I/O of pymb log's one Modbus TCP loop, flat out (see
 * pymb_loop.h). Linux: epoll, MSG_PEEK then MSG_TRUNC on TCP.
 */
#define _GNU_SOURCE /* (MSG_NOSIGNAL, MSG_DONTWAIT and epoll under -std=c99) */
#include <errno.h>
#include <math.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <time.h>

#include "pymb_loop.h"

#define EVENTS 256 /* epoll events one wait takes at most */
#define GAP_MIN 1e-4 /* seconds: a shorter gap is no sleep (a sleep costs about as much) */

double pymbi_loop_now(void)
{
    struct timespec ts;
    if (clock_gettime(CLOCK_MONOTONIC, &ts) != 0) {
        return 0.0;
    }
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* A look: twice the replies' time of late, at least look_min, at most a
 * quarter of the timeout. */
static double look(const pymbi_loop *lp, const pymbi_lconn *c)
{
    double t = 2 * c->took > lp->look_min ? 2 * c->took : lp->look_min;
    double most = c->timeout / 4;
    return t < most ? t : most;
}

/* The bytes of the reply to read request q: MBAP, function, byte count, data. */
static size_t reply_size(const pymbi_mreq *q)
{
    return PYMBI_MASTER_HEAD + (q->function <= 2 ? ((size_t)q->count + 7u) / 8u : 2u * q->count);
}

/* Whether the frames in buf (pymbi_mbap_clean's: whole ones, the last one
 * perhaps still coming) each answer a request of m still in flight, as its
 * reply would begin: its transaction id, no protocol id, its length, unit,
 * function and byte count, as far as they came. A reply to an id not in
 * flight (late or foreign) or of another size is not the poll's. */
static int own_replies(const pymbi_master *m, const uint8_t *buf, size_t len)
{
    size_t pos = 0;
    while (len - pos >= 2) {
        const uint16_t tid = (uint16_t)((buf[pos] << 8) | buf[pos + 1]);
        const pymbi_mslot *s = NULL;
        size_t have = len - pos, want, data, k;
        uint32_t i;
        uint8_t head[9];
        for (i = 0; i < m->span && s == NULL; i++) {
            const pymbi_mslot *t = &m->slots[(uint16_t)(m->oldest + i) % PYMBI_MASTER_INFLIGHT];
            if (t->live && t->tid == tid) {
                s = t;
            }
        }
        if (s == NULL) {
            return 0;
        }
        want = reply_size(&s->req);
        data = want - PYMBI_MASTER_HEAD;
        head[0] = buf[pos];
        head[1] = buf[pos + 1];
        head[2] = 0;
        head[3] = 0;
        head[4] = (uint8_t)((3 + data) >> 8);
        head[5] = (uint8_t)(3 + data);
        head[6] = s->req.unit;
        head[7] = s->req.function;
        head[8] = (uint8_t)data;
        for (k = 2; k < sizeof head && k < have; k++) {
            if (buf[pos + k] != head[k]) {
                return 0;
            }
        }
        if (have <= want) {
            return 1; /* the last reply, whole or still coming */
        }
        pos += want;
    }
    return 1;
}

/* Whether armed c's poll, its look over, is only slow or only looked at
 * late: what came of its replies so far (looked at, not read) is exactly as
 * many bytes as all of them (the loop was busy when they came: the socket is
 * ready, and this wait serves it as any other), or fewer, holding no
 * exception and no impossible header (pymbi_mbap_clean), each reply one of
 * the poll's own (own_replies). */
static int still_clean(const pymbi_loop *lp, const pymbi_lconn *c)
{
    ssize_t got = recv(c->fd, lp->rx, lp->rx_cap, MSG_PEEK | MSG_DONTWAIT);
    if (got < 0) {
        return errno == EAGAIN || errno == EWOULDBLOCK; /* nothing yet */
    }
    if (got > 0 && (size_t)got == c->replies) {
        return 1; /* (epoll says it: SO_RCVLOWAT is their size) */
    }
    return got > 0 && (size_t)got < c->replies && pymbi_mbap_clean(lp->rx, (size_t)got) &&
           own_replies(c->m, lp->rx, (size_t)got);
}

/* A record of `kind` for connection conn (socket fd) at `now`, its other fields 0. */
static void record(pymbi_lrec *r, int kind, int fd, uint32_t conn, double now)
{
    memset(r, 0, sizeof *r);
    r->kind = kind;
    r->fd = fd;
    r->conn = conn;
    r->now = now;
}

static void ready(pymbi_lrec *r, int fd, uint32_t conn, uint32_t events, double now)
{
    record(r, PYMBI_LOOP_READY, fd, conn, now);
    r->events = events;
}

/* TAKEN: of the `got` bytes looked at on c (index i), the master took `used`
 * and `taken` replies, and said `nev` events (an exception, a late, foreign
 * or bad reply): the caller's from here. */
static void taken(pymbi_lrec *r, const pymbi_lconn *c, uint32_t i, double now, int nev,
                  ssize_t got, size_t used, uint64_t replies)
{
    record(r, PYMBI_LOOP_TAKEN, c->fd, i, now);
    r->nev = nev;
    r->got = (size_t)got;
    r->used = used;
    r->taken = replies;
}

/* Armed connection c's poll read in full at `now`: its id to done, its
 * image to the block. */
static void carried(pymbi_loop *lp, const pymbi_lconn *c, double now)
{
    if (lp->block != NULL) {
        memcpy(lp->block + lp->block_len, c->image, c->image_len);
        lp->done_off[lp->ndone] = (uint32_t)lp->block_len;
        lp->done_at[lp->ndone] = now;
        lp->block_len += c->image_len;
    }
    lp->done[lp->ndone++] = c->id;
}

/* The bytes of the replies to m's requests in flight, less the part of one
 * kept (at least 1). */
static size_t rest(const pymbi_master *m)
{
    size_t sum = 0;
    uint32_t i;
    for (i = 0; i < m->span; i++) {
        const pymbi_mslot *t = &m->slots[(uint16_t)(m->oldest + i) % PYMBI_MASTER_INFLIGHT];
        if (t->live) {
            sum += reply_size(&t->req);
        }
    }
    return sum > m->part_len + 1 ? sum - m->part_len : 1;
}

/* Chain c's poll in flight: the socket wakes for any byte until its last
 * request is out, then (a poll of more than one request) for the bytes of
 * all its replies still to come, with a look. A failed setsockopt leaves the
 * wake as it was (any byte, or more: a look then reads them as they come). */
static void aim(const pymbi_loop *lp, pymbi_lconn *c, double now)
{
    size_t want = c->sent == c->n && c->n > 1 ? rest(c->m) : 1;
    int v = want > 0x7FFFFFFF ? 0x7FFFFFFF : (int)want;
    if (v != c->lowat &&
        setsockopt(c->fd, SOL_SOCKET, SO_RCVLOWAT, &v, (socklen_t)sizeof v) == 0) {
        c->lowat = v;
    }
    c->replies = c->lowat > 1 ? (size_t)c->lowat : 0;
    c->look_at = c->lowat > 1 ? now + look(lp, c) : HUGE_VAL;
}

/* Chain c (index i): the next requests of chain[at], as many as the window
 * has room for, framed and sent. Returns 0 (sent, or none to send), 1 when
 * not all went out (an UNSENT record in r: disarmed), -1 on a master that
 * refuses them (a bug). */
static int burst(const pymbi_loop *lp, pymbi_lconn *c, uint32_t i, double now, pymbi_lrec *r)
{
    pymbi_master *m = c->m;
    size_t k = c->n - c->sent, room = c->window > m->in_flight ? c->window - m->in_flight : 0;
    ssize_t sent;
    int framed, err = 0;
    if (k > room) {
        k = room;
    }
    if (k == 0) {
        return 0;
    }
    if (m->in_flight == 0) {
        c->deadline = now + c->timeout;
    }
    framed = pymbi_master_frames(m, c->reqs + c->sent, k, c->image_len, lp->out, lp->out_cap);
    if (framed <= 0) {
        c->armed = 0;
        return -1;
    }
    c->sent += k;
    c->asked += (uint32_t)k;
    c->sent_at = now;
    sent = send(c->fd, lp->out, (size_t)framed, MSG_DONTWAIT | MSG_NOSIGNAL);
    if (sent < 0) {
        err = errno == EAGAIN || errno == EWOULDBLOCK ? 0 : errno;
        sent = 0;
    }
    if ((size_t)sent == (size_t)framed) {
        return 0;
    }
    c->armed = 0; /* the caller says why the connection is lost */
    record(r, PYMBI_LOOP_UNSENT, c->fd, i, now);
    r->size = (size_t)framed;
    r->sent = (size_t)sent;
    r->err = err;
    return 1;
}

/* Chain c (index i) is ready, as serve says (its poll's replies taken as
 * they come; each poll read in full to done and the block, the next one
 * sent; the last one ends the chain: END). */
static int serve_chain(pymbi_loop *lp, pymbi_lconn *c, uint32_t i, uint32_t events, double now,
                       pymbi_lrec *r)
{
    pymbi_master *m = c->m;
    ssize_t got;
    size_t used = 0;
    uint64_t before;
    int nev, whole;

    if ((events & (EPOLLERR | EPOLLHUP)) || !(events & EPOLLIN) || lp->block == NULL ||
        c->at >= c->nchain || c->window == 0) {
        c->armed = 0;
        ready(r, c->fd, i, events, now);
        return 0;
    }
    got = recv(c->fd, lp->rx, lp->rx_cap, MSG_PEEK | MSG_DONTWAIT);
    if (got <= 0 || (c->replies > 0 && (size_t)got != c->replies)) { /* the caller's */
        c->armed = 0;
        ready(r, c->fd, i, events, now);
        return 0;
    }
    before = m->replies;
    nev = pymbi_master_take(m, lp->rx, (size_t)got, c->image, c->image_len, c->ev, c->ev_cap,
                            &used);
    if (nev < 0) {
        c->armed = 0;
        return -1;
    }
    if (nev > 0 || used != (size_t)got) { /* an exception, a late, foreign or bad reply */
        c->armed = 0;
        taken(r, c, i, now, nev, got, used, m->replies - before);
        return 1;
    }
    (void)recv(c->fd, lp->rx, (size_t)got, MSG_TRUNC | MSG_DONTWAIT); /* taken: dropped */
    if (m->in_flight > 0 || c->sent < c->n) { /* the rest of the poll */
        c->deadline = now + c->timeout;
        nev = burst(lp, c, i, now, r);
        if (nev == 0) {
            aim(lp, c, now);
            return 3;
        }
        return nev > 0 ? 0 : -1;
    }
    whole = c->n > 1 && c->n <= c->window;
    if (whole) {
        c->took += (now - c->sent_at - c->took) / 8;
    }
    carried(lp, c, now);
    if (c->at + 1 >= c->nchain) { /* the chain's last poll */
        c->armed = 0;
        record(r, PYMBI_LOOP_END, c->fd, i, now);
        return 0;
    }
    c->at++;
    c->reqs = c->chain[c->at].reqs;
    c->n = c->chain[c->at].n;
    c->image = c->chain[c->at].image;
    c->image_len = c->chain[c->at].image_len;
    c->timeout = c->chain[c->at].timeout;
    c->id = c->chain[c->at].id;
    c->sent = 0;
    nev = burst(lp, c, i, now, r);
    if (nev == 0) {
        aim(lp, c, now);
        return 2;
    }
    return nev > 0 ? 0 : -1;
}

/* The armed connection c (index i) is ready: its whole poll's replies in,
 * taken, the next poll sent whole (2: no record, its id to done) or in part
 * (DONE); or handed back (READY, TAKEN). A chain: serve_chain. Returns 1 when
 * the call must return after this record (TAKEN: rx and the events are this
 * connection's), -1 on a master that refuses its own poll (a bug), else 0 (a
 * record), 2 or 3 (no record; 2: a poll read in full). */
static int serve(pymbi_loop *lp, pymbi_lconn *c, uint32_t i, uint32_t events, double now,
                 pymbi_lrec *r)
{
    ssize_t got, sent;
    size_t used = 0, framed = 0;
    uint64_t before;
    int nev, err = 0;

    if (c->chain != NULL) {
        return serve_chain(lp, c, i, events, now, r);
    }
    if ((events & (EPOLLERR | EPOLLHUP)) || !(events & EPOLLIN)) {
        c->armed = 0;
        ready(r, c->fd, i, events, now);
        return 0;
    }
    got = recv(c->fd, lp->rx, lp->rx_cap, MSG_PEEK | MSG_DONTWAIT);
    if (got <= 0 || (size_t)got != c->replies) { /* not just the poll's replies: the caller's */
        c->armed = 0;
        ready(r, c->fd, i, events, now);
        return 0;
    }
    before = c->m->replies;
    nev = pymbi_master_step(c->m, lp->rx, (size_t)got, c->image, c->image_len, c->ev, c->ev_cap,
                            &used, c->reqs, c->n, lp->out, lp->out_cap, &framed);
    if (nev < 0) {
        c->armed = 0;
        return -1;
    }
    if (framed == 0) { /* an exception, a late, foreign or bad reply: the caller's */
        c->armed = 0;
        taken(r, c, i, now, nev, got, used, c->m->replies - before);
        return 1;
    }
    sent = send(c->fd, lp->out, framed, MSG_DONTWAIT | MSG_NOSIGNAL);
    if (sent < 0) {
        err = errno == EAGAIN || errno == EWOULDBLOCK ? 0 : errno;
        sent = 0;
    }
    record(r, PYMBI_LOOP_DONE, c->fd, i, now);
    r->size = framed;
    r->sent = (size_t)sent;
    r->err = err;
    c->asked += (uint32_t)c->n;
    c->took += (now - c->sent_at - c->took) / 8;
    c->sent_at = now;
    c->deadline = now + c->timeout;
    c->look_at = now + look(lp, c);
    if ((size_t)sent != framed) {
        c->armed = 0; /* the caller says why the connection is lost */
        return 0;
    }
    /* the replies looked at, dropped unread (a short drop: the next recv says it) */
    (void)recv(c->fd, lp->rx, (size_t)got, MSG_TRUNC | MSG_DONTWAIT);
    carried(lp, c, now);
    return 2;
}

/* The looks of the armed connections that are over by `now`: handed back
 * unread (LOOK records from rec[k] on, cap at most) unless only slow; *next
 * brought down to the first look to come, *fastest to the smallest `took`.
 * Returns the records now written. */
static size_t looks(pymbi_loop *lp, double now, pymbi_lrec *rec, size_t k, size_t cap,
                    double *next, double *fastest)
{
    size_t i;
    for (i = 0; i < lp->nconns; i++) {
        pymbi_lconn *c = &lp->conns[i];
        if (!c->armed) {
            continue;
        }
        if (c->took < *fastest) {
            *fastest = c->took;
        }
        if (c->look_at <= now && still_clean(lp, c)) { /* only slow: wait on */
            c->look_at = now + look(lp, c);
        }
        if (c->look_at <= now) {
            if (k == cap) {
                break;
            }
            c->armed = 0;
            memset(&rec[k], 0, sizeof rec[k]);
            rec[k].kind = PYMBI_LOOP_LOOK;
            rec[k].fd = c->fd;
            rec[k].conn = (uint32_t)i;
            rec[k].now = now;
            k++;
        } else if (c->look_at < *next) {
            *next = c->look_at;
        }
    }
    return k;
}


int pymbi_loop_wait(pymbi_loop *lp, double timeout, pymbi_lrec *rec, size_t cap)
{
    struct epoll_event evs[EVENTS];
    size_t k = 0;
    double now, end, first = 0.0;

    if (lp == NULL || rec == NULL || cap == 0 || (lp->nconns > 0 && lp->conns == NULL) ||
        (lp->slot_cap > 0 && lp->slot_of == NULL) || lp->rx == NULL || lp->rx_cap == 0 ||
        lp->out == NULL || lp->nconns >= PYMBI_LOOP_NO_CONN || !(timeout >= 0.0) ||
        lp->done == NULL || lp->done_cap == 0 || !(lp->hold >= 0.0) || !(lp->gap >= 0.0) ||
        (lp->hold > 0.0 && lp->block == NULL) ||
        (lp->block != NULL && (lp->done_off == NULL || lp->done_at == NULL ||
                               lp->block_cap > UINT32_MAX))) {
        errno = EINVAL;
        return -1;
    }
    lp->ndone = 0;
    lp->block_len = 0;
    now = lp->now = pymbi_loop_now();
    end = now + timeout;
    for (;;) {
        double next = end, wait, fastest = HUGE_VAL;
        size_t most;
        int n, j, ms, full = 0;

        if (lp->ndone > 0 && first + lp->hold < next) {
            next = first + lp->hold;
        }
        k = looks(lp, now, rec, k, cap, &next, &fastest);
        if (k == cap) {
            return (int)k;
        }
        if (lp->ndone > 0 && k == 0 && lp->gap > 0.0) { /* held: a gap, one wake for more */
            double gap = fastest * lp->gap;
            if (gap > next - now) {
                gap = next - now;
            }
            if (gap >= GAP_MIN) {
                struct timespec ts;
                ts.tv_sec = (time_t)gap;
                ts.tv_nsec = (long)((gap - (double)ts.tv_sec) * 1e9);
                (void)nanosleep(&ts, NULL); /* (a signal: the epoll wait says so) */
                now = lp->now = pymbi_loop_now();
            }
        }
        wait = k > 0 ? 0.0 : next - now;
        if (lp->ndone > 0 && wait <= 0.0 && k == 0) {
            return 0; /* held as long as it may be */
        }
        ms = wait <= 0.0 ? 0 : wait >= 3600.0 ? 3600000 : (int)ceil(wait * 1e3);
        most = cap - k < EVENTS ? cap - k : EVENTS; /* (one record or done a socket) */
        if (lp->done_cap - lp->ndone < most) {
            most = lp->done_cap - lp->ndone;
        }
        n = epoll_wait(lp->epfd, evs, (int)most, ms);
        if (n < 0) { /* (what was carried first: the next wait fails again) */
            return errno == EINTR || lp->ndone > 0 ? (int)k : -1;
        }
        now = lp->now = pymbi_loop_now();
        for (j = 0; j < n; j++) {
            int fd = evs[j].data.fd;
            int32_t slot = fd >= 0 && (size_t)fd < lp->slot_cap ? lp->slot_of[fd] : -1;
            pymbi_lconn *c;
            size_t had;
            int got;

            if (slot < 0 || (size_t)slot >= lp->nconns) {
                ready(&rec[k++], fd, PYMBI_LOOP_NO_CONN, evs[j].events, now);
                continue;
            }
            c = &lp->conns[slot];
            if (c->armed && lp->block != NULL && c->image_len > lp->block_cap - lp->block_len) {
                if (lp->block_len > 0) { /* the block is full: the next wait says it again */
                    full = 1;
                    break;
                }
                c->armed = 0; /* an image larger than the block: the caller's */
            }
            if (!c->armed || c->fd != fd) {
                ready(&rec[k++], fd, (uint32_t)slot, evs[j].events, now);
                continue;
            }
            had = lp->ndone;
            got = serve(lp, c, (uint32_t)slot, evs[j].events, now, &rec[k]);
            if (got < 0) {
                errno = EINVAL;
                return -1;
            }
            if (had == 0 && lp->ndone > 0) {
                first = now;
            }
            if (got >= 2) {
                continue;
            }
            k++;
            if (got > 0) { /* the rest of the ready sockets: the next wait says them again */
                return (int)k;
            }
        }
        if (k > 0 || full || lp->ndone == 0 || lp->hold <= 0.0 || lp->ndone == lp->done_cap) {
            return (int)k; /* (held: on until the hold, the timeout or a look is over) */
        }
    }
}
