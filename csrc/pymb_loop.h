/* SPDX-License-Identifier: MIT */
/*
 * pymb_loop.h - the I/O of pymb log's one Modbus TCP loop over many
 * connections, flat out: one call waits on the loop's epoll and, for each
 * connection whose whole poll came back, does what the loop would do one
 * Python call at a time: looks at its replies (MSG_PEEK), takes them into
 * the poll's image with its master and frames the next poll in the same
 * step (pymbi_master_step, pymb_master.h), sends it, then drops the replies
 * from the socket (MSG_TRUNC: the requests carry the ACK). Everything else
 * is the caller's: a socket ready that is no such connection (or is one
 * whose bytes are not exactly its poll's replies) is handed back untouched;
 * a take that is not the poll's clean end (an exception, a late, foreign or
 * bad reply) is handed back with its events; a poll slower than its "look"
 * is handed back unread. Policy (schedule, events, reconnects, re-plans) stays
 * with the caller, which arms a connection only while its next poll is the
 * same requests at once, and disarms it whenever that stops being so.
 *
 * With a block (the caller's buffer), each poll read in full has its image
 * copied there as it is read, so a wait may carry a connection's polls more
 * than once: it goes on carrying, without returning, for `hold` seconds after
 * the first poll it read (or until `done` or the block is full), and returns
 * at once for anything that is the caller's. One return hands the caller many
 * polls (its per-wait work is not per-poll work). With a `gap`, a held wait
 * sleeps a little before each epoll wait, so that one wake takes the replies
 * of several polls (a wake is a context switch: as much CPU as a poll's
 * Python).
 *
 * A chain carries a connection's polls one after another (each once, as the
 * caller's schedule has them due): a poll longer than the window is sent a
 * window at a time as its replies come; the socket wakes for any byte until
 * a poll's last request is out, then for the bytes of all its replies still
 * to come (with a look, as a whole poll has); each poll read in full goes to
 * done and the block (a chain needs one), the next one out at once; the last
 * one read ends the chain (PYMBI_LOOP_END). Everything else is handed back as
 * for a flat-out poll.
 *
 * Linux (epoll, SO_RCVLOWAT set by the caller (and by the loop for a chain),
 * MSG_TRUNC on TCP). Compiled
 * into the Python extension only (pymb._native.loop is its one user); not in
 * libpymb. No allocation, no state but the caller's structures; every length
 * is checked.
 */
#ifndef PYMB_LOOP_H
#define PYMB_LOOP_H

#include <stddef.h>
#include <stdint.h>

#include "pymb_master.h"

/* What a record says. */
#define PYMBI_LOOP_READY 1 /* fd is ready (epoll mask `events`), nothing read: the caller's */
#define PYMBI_LOOP_DONE 2  /* conn's poll read in full (its data in its image) at `now`; its
                              next poll framed (`size` bytes) and only `sent` of them sent
                              (`err`: the send's errno, 0: none); disarmed. (A poll read in
                              full whose next poll went out whole is no record: its id
                              goes to the loop's `done`.) */
#define PYMBI_LOOP_TAKEN 3 /* conn's `got` bytes taken by its master but not as the poll's
                              clean end: `nev` events in its ev, `used` bytes used (the rest
                              in the loop's rx from `used` on), `taken` replies into the image;
                              disarmed; the call returns after this record */
#define PYMBI_LOOP_LOOK 4  /* conn's poll is slower than its look and what came of its
                              replies is not clean (pymbi_mbap_clean: an exception, a bad
                              header) or is more than all of them: disarmed, nothing read.
                              (What is only slow gets another look; all of them, come
                              while the caller had the loop, are served as they are.) */
#define PYMBI_LOOP_END 5   /* conn's chain (pymbi_lconn's `chain`) read to its end at `now`:
                              its last poll is in the loop's done and block like the others;
                              disarmed, nothing of the chain in flight */
#define PYMBI_LOOP_UNSENT 6 /* conn's chain: a poll read in full (in done and the block), the
                               next one's requests framed (`size` bytes) and only `sent` of
                               them sent (`err`: the send's errno, 0: none); disarmed */

/* One poll of a chain: its requests, the image their replies fill, the
 * seconds a reply may take, and the caller's name for it (in done). */
typedef struct {
    const pymbi_mreq *reqs;
    size_t n;
    uint8_t *image;
    size_t image_len;
    double timeout;
    uint32_t id;
} pymbi_lpoll;

/* One connection of the loop. The caller fills it and sets `armed` while a
 * poll of it is in flight that the loop carries on: flat out (no chain), a
 * whole poll whose next poll is the same requests, sent at once; or a chain,
 * the polls chain[at] (in flight, `sent` of its requests sent) to
 * chain[nchain - 1], each sent `window` requests at a time as the replies
 * come and the next one sent as soon as one is read in full, until the last
 * is read (PYMBI_LOOP_END). The loop clears `armed` whenever it hands the
 * connection back. */
typedef struct {
    int fd;
    int armed;
    pymbi_master *m;
    const pymbi_mreq *reqs; /* the poll's requests, and the next poll's (a chain: chain[at]'s) */
    size_t n;
    uint8_t *image;
    size_t image_len;
    pymbi_mevent *ev; /* PYMBI_LOOP_TAKEN's events */
    size_t ev_cap;
    size_t replies;  /* bytes of the replies the socket wakes for (its SO_RCVLOWAT): flat out,
                        all of the poll's; a chain: those in flight (0: any byte wakes it) */
    double timeout;  /* seconds a poll's replies may take */
    double took;     /* seconds the replies took, of late (a moving average) */
    double sent_at;  /* when the poll in flight went out (CLOCK_MONOTONIC seconds) */
    double look_at;  /* when it is handed back unread if its replies are not all in */
    double deadline; /* when the poll in flight times out */
    uint32_t asked;  /* requests the loop sent (the caller takes and zeroes the count) */
    uint32_t id;     /* the poll's name in done (flat out; a chain: chain[at].id) */
    const pymbi_lpoll *chain; /* NULL: flat out */
    size_t nchain;
    size_t at;
    size_t sent;     /* a chain: requests of chain[at] sent */
    size_t window;   /* a chain: requests in flight at most */
    int lowat;       /* a chain: the socket's SO_RCVLOWAT (the loop sets it) */
} pymbi_lconn;

typedef struct {
    int kind;        /* PYMBI_LOOP_* */
    int fd;
    uint32_t conn;   /* the connection's index (READY: PYMBI_LOOP_NO_CONN if none) */
    uint32_t events; /* READY: the epoll mask */
    int err;         /* DONE: the send's errno (0: none) */
    int nev;         /* TAKEN: the events */
    size_t size;     /* DONE: bytes of the next poll */
    size_t sent;     /* DONE: of those, sent */
    size_t got;      /* TAKEN: bytes taken */
    size_t used;     /* TAKEN: of those, used */
    uint64_t taken;  /* TAKEN: replies taken into the image */
    double now;      /* when the loop looked (CLOCK_MONOTONIC seconds) */
} pymbi_lrec;

#define PYMBI_LOOP_NO_CONN 0xFFFFFFFFu

typedef struct {
    int epfd;
    pymbi_lconn *conns;
    size_t nconns;
    const int32_t *slot_of; /* fd -> index into conns (-1: none); fds >= slot_cap: none */
    size_t slot_cap;
    uint8_t *rx; /* a poll's replies are looked at here */
    size_t rx_cap;
    uint8_t *out; /* the next poll is framed here */
    size_t out_cap;
    double look_min; /* a look is twice `took`, at least this, at most timeout / 4 */
    uint32_t *done;  /* the ids of the polls a wait read in full (their connections stay
                        armed, but for a chain's PYMBI_LOOP_END and UNSENT) */
    size_t done_cap;
    size_t ndone;    /* of done, written by the last wait */
    double now;      /* when the last wait looked (CLOCK_MONOTONIC seconds) */
    /* The block (NULL: none, and hold must be 0): done[j]'s image copied to
     * block[done_off[j] .. + its image_len), read at done_at[j]; a connection
     * whose image would not fit is handed back (READY) when the block is
     * empty, else left for the next wait. done_off and done_at: done_cap each. */
    uint8_t *block;
    size_t block_cap;
    size_t block_len; /* of block, written by the last wait */
    uint32_t *done_off;
    double *done_at;
    double hold; /* seconds a wait goes on carrying after its first poll read (0: returns) */
    /* While held, the wait sleeps this share of the fastest armed poll's reply
     * time (`took`) before each epoll wait, when that is 100 us or more (0:
     * never): the replies that come meanwhile are taken in one wake, each
     * poll's next one sent later by at most that share of its replies' time. */
    double gap;
} pymbi_loop;

/* CLOCK_MONOTONIC in seconds (as Python's time.monotonic on Linux). */
double pymbi_loop_now(void);

/* Wait up to `timeout` seconds (rounded up to a millisecond; sooner when an
 * armed connection's look comes first) on lp->epfd: the ids of the polls read
 * in full (flat out, the next one sent whole) to lp->done[0 .. lp->ndone) (with a
 * block: their images and times too), the last at lp->now; everything else to
 * rec[0 .. cap). It returns after the first epoll wake that read a poll or
 * wrote a record, or with a block, once a record is written, lp->hold seconds
 * after the first poll read, when done or the block is full, or at the
 * timeout. Returns the records written (0 and no done: the time passed, or a
 * signal came), -1 with errno on invalid arguments or an epoll failure (with
 * nothing carried: a wait that carried polls returns them first). */
int pymbi_loop_wait(pymbi_loop *lp, double timeout, pymbi_lrec *rec, size_t cap);

#endif
