/* SPDX-License-Identifier: MIT */
/*
 * test_loop.c - pymb log's TCP loop I/O (pymb_loop.h) against a peer on a
 * real loopback TCP connection: a whole poll's replies taken and the next
 * poll sent in one wait, sockets handed back untouched (not armed, not a
 * connection, bytes that are not just the poll's replies, a closed peer), a
 * take that is not the poll's clean end handed back with its events, a look
 * that is over, a chain of polls read one after another, invalid arguments.
 * No Python, no libmodbus.
 *
 * Source: [MB-TCP] 3.1.3 (MBAP), [MB-APP] 6.3-6.4 (reads of registers).
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../pymb.h"
#include "../pymb_loop.h"
#include "check.h"

static pymbi_master M; /* (large: not on the stack) */

/* A loopback TCP connection: *client non-blocking (the loop's), *peer blocking. */
static int pair(int *client, int *peer)
{
    struct sockaddr_in a;
    socklen_t len = sizeof a;
    int one = 1, lfd = socket(AF_INET, SOCK_STREAM, 0);
    if (lfd < 0) {
        return -1;
    }
    memset(&a, 0, sizeof a);
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(lfd, (struct sockaddr *)&a, sizeof a) != 0 || listen(lfd, 1) != 0 ||
        getsockname(lfd, (struct sockaddr *)&a, &len) != 0) {
        close(lfd);
        return -1;
    }
    *client = socket(AF_INET, SOCK_STREAM, 0);
    if (*client < 0 || connect(*client, (struct sockaddr *)&a, sizeof a) != 0) {
        close(lfd);
        return -1;
    }
    *peer = accept(lfd, NULL, NULL);
    close(lfd);
    if (*peer < 0) {
        return -1;
    }
    setsockopt(*client, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    setsockopt(*peer, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    return fcntl(*client, F_SETFL, fcntl(*client, F_GETFL) | O_NONBLOCK);
}

static pymbi_mreq rq(unsigned address, unsigned count, unsigned offset, uint32_t token)
{
    pymbi_mreq r;
    memset(&r, 0, sizeof r);
    r.unit = 1;
    r.function = 0x03;
    r.address = (uint16_t)address;
    r.count = (uint16_t)count;
    r.offset = offset;
    r.token = token;
    return r;
}

/* The reply to a read of `count` holding registers under `tid`, data bytes
 * fill, fill + 1, ...: its length. */
static size_t reply(uint8_t *out, unsigned tid, unsigned count, uint8_t fill)
{
    size_t i, nb = 2 * count;
    const uint8_t head[9] = {(uint8_t)(tid >> 8), (uint8_t)tid, 0, 0, (uint8_t)((3 + nb) >> 8),
                             (uint8_t)(3 + nb), 1, 0x03, (uint8_t)nb};
    memcpy(out, head, sizeof head);
    for (i = 0; i < nb; i++) {
        out[9 + i] = (uint8_t)(fill + i);
    }
    return 9 + nb;
}

/* Exactly n bytes from the blocking peer. */
static int read_n(int fd, uint8_t *buf, size_t n)
{
    size_t have = 0;
    while (have < n) {
        ssize_t got = recv(fd, buf + have, n - have, 0);
        if (got <= 0) {
            return -1;
        }
        have += (size_t)got;
    }
    return 0;
}

typedef struct {
    int ep, client, peer;
    int32_t slot_of[1024];
    uint8_t rx[4096], out[1024], image[8];
    pymbi_mreq reqs[2];
    pymbi_mevent ev[8];
    pymbi_lconn conn;
    pymbi_loop lp;
    pymbi_lrec rec[8];
    uint32_t done[8];
} fixture;

static fixture F;

/* A connection with a poll of two reads (2 registers at 0, 2 at 10) framed
 * and sent, the peer having read it; armed when `armed`. */
static int setup(int armed)
{
    struct epoll_event e;
    uint8_t got[24];
    int lowat = 2 * 13;
    size_t i;
    memset(&F, 0, sizeof F);
    for (i = 0; i < 1024; i++) {
        F.slot_of[i] = -1;
    }
    if (pair(&F.client, &F.peer) != 0 || F.client >= 1024) {
        return -1;
    }
    F.ep = epoll_create1(0);
    memset(&e, 0, sizeof e);
    e.events = EPOLLIN;
    e.data.fd = F.client;
    if (F.ep < 0 || epoll_ctl(F.ep, EPOLL_CTL_ADD, F.client, &e) != 0) {
        return -1;
    }
    F.slot_of[F.client] = 0;
    F.reqs[0] = rq(0, 2, 0, 0);
    F.reqs[1] = rq(10, 2, 4, 1);
    pymbi_master_reset(&M, 1);
    if (pymbi_master_frames(&M, F.reqs, 2, sizeof F.image, F.out, sizeof F.out) != 24 ||
        send(F.client, F.out, 24, 0) != 24 || read_n(F.peer, got, 24) != 0) {
        return -1;
    }
    setsockopt(F.client, SOL_SOCKET, SO_RCVLOWAT, &lowat, sizeof lowat);
    F.conn.fd = F.client;
    F.conn.armed = armed;
    F.conn.m = &M;
    F.conn.reqs = F.reqs;
    F.conn.n = 2;
    F.conn.image = F.image;
    F.conn.image_len = sizeof F.image;
    F.conn.ev = F.ev;
    F.conn.ev_cap = 8;
    F.conn.replies = 26;
    F.conn.timeout = 1.0;
    F.conn.sent_at = pymbi_loop_now();
    F.conn.look_at = F.conn.sent_at + 5.0;
    F.conn.deadline = F.conn.sent_at + 1.0;
    F.lp.epfd = F.ep;
    F.lp.conns = &F.conn;
    F.lp.nconns = 1;
    F.lp.slot_of = F.slot_of;
    F.lp.slot_cap = 1024;
    F.lp.rx = F.rx;
    F.lp.rx_cap = sizeof F.rx;
    F.lp.out = F.out;
    F.lp.out_cap = sizeof F.out;
    F.lp.look_min = 0.002;
    F.lp.done = F.done;
    F.lp.done_cap = 8;
    return 0;
}

static void teardown(void)
{
    close(F.client);
    if (F.peer >= 0) {
        close(F.peer);
    }
    close(F.ep);
}

/* The peer answers both requests (tids 1 and 2, the second first). */
static void answer(unsigned tid1, unsigned tid2)
{
    uint8_t buf[32];
    size_t n = reply(buf, tid2, 2, 0x50);
    n += reply(buf + n, tid1, 2, 0x10);
    CHECK(send(F.peer, buf, n, 0) == (ssize_t)n);
}

static void test_done(void)
{
    uint8_t next[24];
    uint8_t none;
    int n;
    CHECK(setup(1) == 0);
    answer(1, 2);
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 0); /* no record: the connection is in done */
    CHECK(F.lp.ndone == 1 && F.done[0] == 0);
    CHECK(F.image[0] == 0x10 && F.image[3] == 0x13 && F.image[4] == 0x50 && F.image[7] == 0x53);
    CHECK(F.conn.armed == 1 && F.conn.asked == 2 && M.in_flight == 2);
    CHECK(F.conn.sent_at == F.lp.now && F.conn.deadline == F.lp.now + 1.0);
    CHECK(F.conn.look_at > F.lp.now && F.conn.look_at <= F.lp.now + 0.25);
    /* the next poll reached the peer (tids 3 and 4); the replies left the socket */
    CHECK(read_n(F.peer, next, 24) == 0);
    CHECK(next[0] == 0 && next[1] == 3 && next[12] == 0 && next[13] == 4 && next[7] == 0x03);
    CHECK(recv(F.client, &none, 1, MSG_DONTWAIT) < 0 && errno == EAGAIN);
    /* and again, with the next poll's replies */
    F.conn.look_at = pymbi_loop_now() + 5.0;
    answer(3, 4);
    CHECK(pymbi_loop_wait(&F.lp, 2.0, F.rec, 8) == 0 && F.lp.ndone == 1);
    CHECK(F.conn.asked == 4 && M.replies == 4);
    /* the next poll cannot go out (the writing side shut): DONE with the errno, disarmed */
    F.conn.look_at = pymbi_loop_now() + 5.0;
    CHECK(shutdown(F.client, SHUT_WR) == 0);
    answer(5, 6);
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 1 && F.lp.ndone == 0 && F.rec[0].kind == PYMBI_LOOP_DONE);
    CHECK(F.rec[0].size == 24 && F.rec[0].sent == 0 && F.rec[0].err == EPIPE);
    CHECK(F.conn.armed == 0 && M.replies == 6);
    teardown();
}

static void test_ready(void)
{
    uint8_t buf[64];
    int other[2];
    struct epoll_event e;
    int n;
    /* not armed: handed back, nothing read */
    CHECK(setup(0) == 0);
    answer(1, 2);
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_READY && F.rec[0].conn == 0);
    CHECK((F.rec[0].events & EPOLLIN) != 0);
    CHECK(recv(F.client, buf, sizeof buf, MSG_DONTWAIT) == 26);
    CHECK(M.replies == 0);
    teardown();
    /* a socket that is no connection of the loop */
    CHECK(setup(1) == 0);
    CHECK(socketpair(AF_UNIX, SOCK_STREAM, 0, other) == 0);
    memset(&e, 0, sizeof e);
    e.events = EPOLLIN;
    e.data.fd = other[0];
    CHECK(epoll_ctl(F.ep, EPOLL_CTL_ADD, other[0], &e) == 0);
    CHECK(write(other[1], "x", 1) == 1);
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_READY && F.rec[0].conn == PYMBI_LOOP_NO_CONN);
    CHECK(F.rec[0].fd == other[0] && F.conn.armed == 1);
    close(other[0]);
    close(other[1]);
    /* armed, but more than the poll's replies came: handed back untouched */
    answer(1, 2);
    CHECK(send(F.peer, "\0", 1, 0) == 1);
    usleep(20000);
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_READY && F.rec[0].conn == 0);
    CHECK(F.conn.armed == 0 && M.replies == 0);
    CHECK(recv(F.client, buf, sizeof buf, MSG_DONTWAIT) == 27);
    teardown();
    /* armed, the peer closed: handed back */
    CHECK(setup(1) == 0);
    close(F.peer);
    F.peer = -1;
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_READY && F.conn.armed == 0);
    teardown();
}

static void test_taken(void)
{
    uint8_t buf[32];
    size_t n;
    int got;
    /* the poll's bytes, but the second reply is under an id never sent */
    CHECK(setup(1) == 0);
    n = reply(buf, 1, 2, 0x10);
    n += reply(buf + n, 99, 2, 0x50);
    CHECK(send(F.peer, buf, n, 0) == (ssize_t)n);
    got = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(got == 1 && F.rec[0].kind == PYMBI_LOOP_TAKEN && F.rec[0].conn == 0);
    CHECK(F.rec[0].nev == 1 && F.ev[0].kind == PYMBI_EV_FOREIGN && F.ev[0].tid == 99);
    CHECK(F.rec[0].got == 26 && F.rec[0].used == 26 && F.rec[0].taken == 1);
    CHECK(F.conn.armed == 0 && M.in_flight == 1 && F.conn.asked == 0);
    CHECK(F.image[0] == 0x10 && F.image[4] == 0);
    teardown();
}

static void test_look(void)
{
    uint8_t buf[64];
    int n;
    /* a look over whose replies all came (the caller had the loop meanwhile,
     * as on a loaded machine): served as they are, not handed back */
    CHECK(setup(1) == 0);
    answer(1, 2);
    usleep(20000);
    F.conn.look_at = pymbi_loop_now() - 0.001;
    n = pymbi_loop_wait(&F.lp, 0.0, F.rec, 8);
    CHECK(n == 0 && F.lp.ndone == 1 && F.done[0] == 0);
    CHECK(F.conn.armed == 1 && M.replies == 2 && F.conn.asked == 2);
    CHECK(F.conn.look_at > F.lp.now - 0.001);
    CHECK(recv(F.client, buf, sizeof buf, MSG_DONTWAIT) < 0 && errno == EAGAIN);
    teardown();
    /* ... and with more than all of them (a reply no request asked for): handed back */
    CHECK(setup(1) == 0);
    answer(1, 2);
    {
        uint8_t one[16];
        size_t len = reply(one, 9, 1, 0x50);
        CHECK(send(F.peer, one, len, 0) == (ssize_t)len);
    }
    usleep(20000);
    F.conn.look_at = pymbi_loop_now() - 0.001;
    n = pymbi_loop_wait(&F.lp, 0.0, F.rec, 8);
    CHECK(n >= 1 && F.rec[0].kind == PYMBI_LOOP_LOOK && F.rec[0].conn == 0);
    CHECK(n == 1 || (n == 2 && F.rec[1].kind == PYMBI_LOOP_READY)); /* (then: as a socket) */
    CHECK(F.conn.armed == 0 && M.replies == 0);
    CHECK(recv(F.client, buf, sizeof buf, MSG_DONTWAIT) == 26 + 11);
    teardown();
    /* a look over with nothing come yet: only slow, another look, still armed */
    CHECK(setup(1) == 0);
    F.conn.look_at = pymbi_loop_now() - 0.001;
    n = pymbi_loop_wait(&F.lp, 0.0, F.rec, 8);
    CHECK(n == 0 && F.lp.ndone == 0 && F.conn.armed == 1);
    CHECK(F.conn.look_at > pymbi_loop_now() - 0.001);
    /* ... and with a first clean reply in: the same */
    {
        uint8_t one[16];
        size_t len = reply(one, 2, 2, 0x50);
        CHECK(send(F.peer, one, len, 0) == (ssize_t)len);
        usleep(20000);
        F.conn.look_at = pymbi_loop_now() - 0.001;
        n = pymbi_loop_wait(&F.lp, 0.0, F.rec, 8);
        CHECK(n == 0 && F.conn.armed == 1);
        /* an exception after it: handed back (a look), nothing read */
        {
            const uint8_t exc[9] = {0, 1, 0, 0, 0, 3, 1, 0x83, 0x02};
            CHECK(send(F.peer, exc, sizeof exc, 0) == (ssize_t)sizeof exc);
        }
        usleep(20000);
        F.conn.look_at = pymbi_loop_now() - 0.001;
        n = pymbi_loop_wait(&F.lp, 0.0, F.rec, 8);
        CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_LOOK && F.conn.armed == 0);
        CHECK(recv(F.client, buf, sizeof buf, MSG_DONTWAIT) == (ssize_t)(len + 9));
    }
    teardown();
    /* a well-formed reply that is not one of the poll's (an id never sent, a
     * size other than asked): handed back at the look, not waited on */
    {
        uint8_t one[16];
        const unsigned tids[2] = {7, 1};
        const unsigned counts[2] = {2, 1};
        size_t t;
        for (t = 0; t < 2; t++) {
            size_t len = reply(one, tids[t], counts[t], 0x50);
            CHECK(setup(1) == 0);
            CHECK(send(F.peer, one, len, 0) == (ssize_t)len);
            usleep(20000);
            F.conn.look_at = pymbi_loop_now() - 0.001;
            n = pymbi_loop_wait(&F.lp, 0.0, F.rec, 8);
            CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_LOOK && F.conn.armed == 0);
            CHECK(recv(F.client, buf, sizeof buf, MSG_DONTWAIT) == (ssize_t)len);
            teardown();
        }
    }
    CHECK(setup(1) == 0);
    /* a look to come shortens the wait */
    F.conn.armed = 1;
    F.conn.look_at = pymbi_loop_now() + 0.05;
    n = pymbi_loop_wait(&F.lp, 5.0, F.rec, 8);
    CHECK(n == 0 && F.conn.armed == 1);
    CHECK(pymbi_loop_now() >= F.conn.look_at);
    teardown();
}

/* The peer of test_block, in a thread of its own: answers `polls` polls of
 * the fixture's two reads (the first one read by setup), poll t's data bytes
 * 0x10 + 0x20 t, ... and 0x18 + 0x20 t, ..., reading each next poll first. */
typedef struct {
    int polls;
    int failed;
} peer_job;

static void *peer_polls(void *arg)
{
    peer_job *job = arg;
    uint8_t buf[32], got[24];
    int t;
    for (t = 0; t < job->polls; t++) {
        const unsigned tid = 1u + 2u * (unsigned)t;
        size_t n;
        if (t > 0 && read_n(F.peer, got, 24) != 0) {
            job->failed = 1;
            break;
        }
        n = reply(buf, tid, 2, (uint8_t)(0x10 + 0x20 * t));
        n += reply(buf + n, tid + 1, 2, (uint8_t)(0x18 + 0x20 * t));
        if (send(F.peer, buf, n, 0) != (ssize_t)n) {
            job->failed = 1;
            break;
        }
    }
    return NULL;
}

static uint8_t Block[64];
static uint32_t Off[8];
static double At[8];

/* setup(1) with the block (`cap` bytes of it) and `hold`. */
static int setup_block(size_t cap, double hold)
{
    if (setup(1) != 0) {
        return -1;
    }
    memset(Block, 0, sizeof Block);
    F.lp.block = Block;
    F.lp.block_cap = cap;
    F.lp.done_off = Off;
    F.lp.done_at = At;
    F.lp.hold = hold;
    return 0;
}

static void test_block(void)
{
    peer_job job;
    pthread_t th;
    double t0;
    int n, j;
    /* three polls carried in one wait (done holds three), each image in the block */
    CHECK(setup_block(sizeof Block, 5.0) == 0);
    F.lp.done_cap = 3;
    job.polls = 3;
    job.failed = 0;
    CHECK(pthread_create(&th, NULL, peer_polls, &job) == 0);
    n = pymbi_loop_wait(&F.lp, 5.0, F.rec, 8);
    CHECK(pthread_join(th, NULL) == 0 && job.failed == 0);
    CHECK(n == 0 && F.lp.ndone == 3 && F.lp.block_len == 24);
    for (j = 0; j < 3; j++) {
        const uint8_t *im = Block + 8 * j;
        CHECK(F.done[j] == 0 && Off[j] == 8u * (unsigned)j);
        CHECK(im[0] == 0x10 + 0x20 * j && im[3] == 0x13 + 0x20 * j);
        CHECK(im[4] == 0x18 + 0x20 * j && im[7] == 0x1b + 0x20 * j);
        CHECK(j == 0 || At[j] >= At[j - 1]);
    }
    CHECK(At[2] == F.lp.now && F.conn.armed == 1 && F.conn.asked == 6 && M.replies == 6);
    teardown();
    /* held: the wait goes on `hold` seconds after its first poll, then returns it */
    CHECK(setup_block(sizeof Block, 0.05) == 0);
    answer(1, 2);
    t0 = pymbi_loop_now();
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 0 && F.lp.ndone == 1 && F.lp.block_len == 8 && Block[0] == 0x10);
    CHECK(pymbi_loop_now() - At[0] >= 0.049 && pymbi_loop_now() - t0 < 1.0);
    CHECK(F.conn.armed == 1 && M.in_flight == 2);
    teardown();
    /* room for one image: the second poll is the next wait's */
    CHECK(setup_block(8, 5.0) == 0);
    job.polls = 2;
    job.failed = 0;
    CHECK(pthread_create(&th, NULL, peer_polls, &job) == 0);
    n = pymbi_loop_wait(&F.lp, 5.0, F.rec, 8);
    CHECK(n == 0 && F.lp.ndone == 1 && F.lp.block_len == 8 && Block[0] == 0x10);
    F.lp.hold = 0.01;
    n = pymbi_loop_wait(&F.lp, 5.0, F.rec, 8);
    CHECK(pthread_join(th, NULL) == 0 && job.failed == 0);
    CHECK(n == 0 && F.lp.ndone == 1 && F.lp.block_len == 8 && Block[0] == 0x30);
    CHECK(F.conn.asked == 4 && M.replies == 4);
    teardown();
    /* with a gap, the held wait sleeps a share of the replies' time before
     * it looks again: the second poll, answered at once, is taken after it */
    CHECK(setup_block(sizeof Block, 2.0) == 0);
    F.lp.done_cap = 2;
    F.lp.gap = 0.5;
    F.conn.took = 0.04; /* (after the first poll: at least 0.035, a gap of 17 ms or more) */
    job.polls = 2;
    job.failed = 0;
    CHECK(pthread_create(&th, NULL, peer_polls, &job) == 0);
    n = pymbi_loop_wait(&F.lp, 5.0, F.rec, 8);
    CHECK(pthread_join(th, NULL) == 0 && job.failed == 0);
    CHECK(n == 0 && F.lp.ndone == 2 && Block[0] == 0x10 && Block[8] == 0x30);
    CHECK(At[1] - At[0] >= 0.017);
    teardown();
    /* an image larger than the block: handed back, nothing read */
    CHECK(setup_block(4, 5.0) == 0);
    answer(1, 2);
    n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_READY && F.rec[0].conn == 0);
    CHECK(F.lp.ndone == 0 && F.conn.armed == 0 && M.replies == 0);
    teardown();
}

/* A chain's peer: answers each request as it comes (`answers` of them; the
 * one numbered `refuse` with exception 02, 0: none), then reads on until
 * the connection closes without answering. */
typedef struct {
    int answers, refuse, failed;
} chain_job;

static void *peer_requests(void *arg)
{
    chain_job *job = arg;
    uint8_t req[12], buf[32];
    int t;
    for (t = 1; t <= job->answers; t++) {
        unsigned tid;
        size_t n;
        if (read_n(F.peer, req, 12) != 0) {
            job->failed = 1;
            return NULL;
        }
        tid = (unsigned)(req[0] << 8 | req[1]);
        if (t == job->refuse) {
            const uint8_t exc[9] = {req[0], req[1], 0, 0, 0, 3, 1, 0x83, 0x02};
            memcpy(buf, exc, sizeof exc);
            n = sizeof exc;
        } else {
            n = reply(buf, tid, 2, (uint8_t)(0x10 * t));
        }
        if (send(F.peer, buf, n, 0) != (ssize_t)n) {
            job->failed = 1;
            return NULL;
        }
    }
    while (recv(F.peer, req, sizeof req, 0) > 0) {
    }
    return NULL;
}

static uint8_t ImageB[8];
static pymbi_lpoll Chain[2];

/* A chain of two polls of two reads each (ids 7 and 9, images F.image and
 * ImageB), one request at a time: the first request of the first poll sent,
 * the peer having read nothing yet; the block, no hold. */
static int setup_chain(void)
{
    int one = 1;
    if (setup_block(sizeof Block, 0.0) != 0) {
        return -1;
    }
    pymbi_master_reset(&M, 1);
    if (pymbi_master_frames(&M, F.reqs, 1, sizeof F.image, F.out, sizeof F.out) != 12 ||
        send(F.client, F.out, 12, 0) != 12) {
        return -1;
    }
    setsockopt(F.client, SOL_SOCKET, SO_RCVLOWAT, &one, sizeof one);
    memset(ImageB, 0, sizeof ImageB);
    Chain[0].reqs = F.reqs;
    Chain[0].n = 2;
    Chain[0].image = F.image;
    Chain[0].image_len = sizeof F.image;
    Chain[0].timeout = 1.0;
    Chain[0].id = 7;
    Chain[1] = Chain[0];
    Chain[1].image = ImageB;
    Chain[1].id = 9;
    F.conn.chain = Chain;
    F.conn.nchain = 2;
    F.conn.at = 0;
    F.conn.sent = 1;
    F.conn.window = 1;
    F.conn.lowat = 1;
    F.conn.replies = 0;
    F.conn.look_at = HUGE_VAL;
    F.conn.id = 7;
    F.conn.armed = 1;
    return 0;
}

/* Waits until a record or `most` waits: the records of the last. */
static int wait_record(int most)
{
    int n = 0;
    uint32_t ids[8];
    size_t got = 0, j;
    while (most-- > 0 && (n = pymbi_loop_wait(&F.lp, 2.0, F.rec, 8)) == 0) {
        for (j = 0; j < F.lp.ndone && got < 8; j++) {
            ids[got++] = F.done[j];
        }
    }
    for (j = 0; j < F.lp.ndone && got < 8; j++) {
        ids[got++] = F.done[j];
    }
    memcpy(F.done, ids, got * sizeof ids[0]);
    F.lp.ndone = got;
    return n;
}

static void test_chain(void)
{
    chain_job job = {4, 0, 0};
    pthread_t th;
    int n;
    /* each request answered as it comes: both polls read, one after another */
    CHECK(setup_chain() == 0);
    CHECK(pthread_create(&th, NULL, peer_requests, &job) == 0);
    n = wait_record(20);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_END && F.rec[0].conn == 0);
    CHECK(F.lp.ndone == 2 && F.done[0] == 7 && F.done[1] == 9);
    CHECK(F.image[0] == 0x10 && F.image[4] == 0x20 && ImageB[0] == 0x30 && ImageB[4] == 0x40);
    CHECK(F.conn.armed == 0 && M.in_flight == 0 && F.conn.asked == 3 && M.replies == 4);
    CHECK(F.conn.at == 1 && F.conn.sent == 2);
    shutdown(F.client, SHUT_RDWR);
    CHECK(pthread_join(th, NULL) == 0 && job.failed == 0);
    teardown();
    /* the second poll's first request refused: handed back with its event */
    CHECK(setup_chain() == 0);
    job.answers = 3;
    job.refuse = 3;
    CHECK(pthread_create(&th, NULL, peer_requests, &job) == 0);
    n = wait_record(20);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_TAKEN && F.rec[0].nev == 1);
    CHECK(F.ev[0].kind == PYMBI_EV_EXCEPTION && F.ev[0].code == 2 && F.ev[0].token == 0);
    CHECK(F.lp.ndone == 1 && F.done[0] == 7 && F.conn.armed == 0 && F.conn.at == 1);
    shutdown(F.client, SHUT_RDWR);
    CHECK(pthread_join(th, NULL) == 0 && job.failed == 0);
    teardown();
    /* a device silent after the first poll: still armed, its deadline the
     * second poll's request's (the caller times it out) */
    CHECK(setup_chain() == 0);
    job.answers = 2;
    job.refuse = 0;
    job.failed = 0;
    CHECK(pthread_create(&th, NULL, peer_requests, &job) == 0);
    n = wait_record(3);
    CHECK(n == 0 && F.lp.ndone == 1 && F.done[0] == 7 && F.conn.armed == 1);
    CHECK(F.conn.at == 1 && F.conn.sent == 1 && M.in_flight == 1);
    CHECK(F.conn.deadline > F.conn.sent_at && F.conn.deadline - F.conn.sent_at <= 1.0 + 1e-9);
    shutdown(F.client, SHUT_RDWR);
    CHECK(pthread_join(th, NULL) == 0 && job.failed == 0);
    teardown();
    /* a poll of both requests at once (a window of 2): its replies wake the
     * socket once (SO_RCVLOWAT), with a look */
    CHECK(setup_chain() == 0);
    job.answers = 4;
    job.failed = 0;
    F.conn.window = 2;
    CHECK(pthread_create(&th, NULL, peer_requests, &job) == 0);
    n = wait_record(20);
    CHECK(n == 1 && F.rec[0].kind == PYMBI_LOOP_END && F.lp.ndone == 2);
    CHECK(F.conn.lowat == 26 && ImageB[0] == 0x30 && ImageB[4] == 0x40);
    shutdown(F.client, SHUT_RDWR);
    CHECK(pthread_join(th, NULL) == 0 && job.failed == 0);
    teardown();
}

static void test_args(void)
{
    pymbi_lrec r;
    CHECK(setup(1) == 0);
    errno = 0;
    CHECK(pymbi_loop_wait(NULL, 0.0, &r, 1) == -1 && errno == EINVAL);
    CHECK(pymbi_loop_wait(&F.lp, 0.0, NULL, 1) == -1 && errno == EINVAL);
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 0) == -1 && errno == EINVAL);
    CHECK(pymbi_loop_wait(&F.lp, -1.0, &r, 1) == -1 && errno == EINVAL);
    F.lp.rx = NULL;
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 1) == -1 && errno == EINVAL);
    F.lp.rx = F.rx;
    F.lp.done = NULL;
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 1) == -1 && errno == EINVAL);
    F.lp.done = F.done;
    F.lp.hold = 0.1; /* a hold needs a block */
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 1) == -1 && errno == EINVAL);
    F.lp.block = Block;
    F.lp.block_cap = sizeof Block;
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 1) == -1 && errno == EINVAL); /* and its arrays */
    F.lp.done_off = Off;
    F.lp.done_at = At;
    F.lp.hold = -1.0;
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 1) == -1 && errno == EINVAL);
    F.lp.hold = 0.1;
    F.lp.gap = -1.0;
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 1) == -1 && errno == EINVAL);
    F.lp.gap = 0.0;
    CHECK(pymbi_loop_wait(&F.lp, 0.0, &r, 1) == 0 && F.lp.ndone == 0);
    teardown();
}

int main(void)
{
    test_done();
    test_ready();
    test_taken();
    test_look();
    test_block();
    test_chain();
    test_args();
    return check_report();
}
