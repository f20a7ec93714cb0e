/* SPDX-License-Identifier: MIT */
/*
 * pymb_internal.h - the line, the transport table and the helpers shared by
 * the request-path sources; not installed. Internal functions shared between
 * files are named pymbi_*: the version script exports pymb_* only.
 */
#ifndef PYMB_INTERNAL_H
#define PYMB_INTERNAL_H

#include <sys/types.h>

#include "pymb_map_ready.h"
#include "pymb_modbus.h"

/* [MB-TCP] 3.1.3: transaction id, protocol id, length, unit id. */
#define PYMB_MBAP_LENGTH 7

typedef struct pymb_transport pymb_transport;

struct pymb_line {
    modbus_t *ctx;
    const pymb_transport *tr; /* chosen by pymb_line_new */
    uint32_t silence_us;      /* RTU: the silence that ends a reply of unknown length */
    int (*interrupted)(void *arg);
    void *interrupt_arg;
    uint32_t char_ns;         /* RTU: one character's wire time, 0: no early-byte check */
    uint16_t tid;             /* TCP, UDP: the last MBAP transaction id sent */
    int retries;              /* UDP: sends of a request again after a timeout */
    int owed;                 /* a quiet window is owed (after a failure) */
    int owed_slave;           /* the address the failed request went to */
    uint64_t owed_since_us;   /* when it failed: CLOCK_MONOTONIC, microseconds */
    int rx_extra;             /* bytes after the last reply in the same read */
    pymb_line_io io;          /* io.read NULL: the socket's own read and send */
};

/*
 * A transport: how a request is framed, sent, received and checked. One
 * const table per transport, in its own file (pymb_rtu.c, pymb_tcp.c,
 * pymb_rtu_tcp.c, pymb_ascii.c, pymb_udp.c), listed in transports[]
 * (pymb_line.c) and chosen by pymb_line_new; pymb_line_connect/close and the
 * request path (pymb_request.c) call only these. A new transport is one new
 * file and one line in that list.
 */
struct pymb_transport {
    pymb_framing framing;
    int ctx_header_length; /* what modbus_get_header_length says of a fitting context */
    int header_length;     /* ADU bytes before the function code */
    int trailer_length;    /* ADU bytes after the PDU (the RTU CRC) */
    int lowest_slave;      /* the lowest address a read may go to (1 where 0 broadcasts) */
    int broadcast;         /* address 0 is a broadcast: sent, never answered */
    /* Before a request to `slave`: drop stray input or pay a quiet window
     * owed after a failure. 0, or -1 and errno. */
    int (*prepare)(pymb_line *line, int slave);
    /* The ADU for req (address + PDU) in adu[0..cap): its length. */
    int (*build)(pymb_line *line, const uint8_t *req, int req_len, uint8_t *adu, int cap);
    /* Send a built ADU: 0, or -1 and errno. */
    int (*send)(pymb_line *line, const uint8_t *adu, int len);
    /* After a broadcast has been handed over: wait until it has left. */
    void (*flush_output)(pymb_line *line);
    /* The reply ADU's total length from its first `have` bytes; expect: the
     * reply PDU's length when the caller knows it (0: not). A negative
     * pymb_frame_status: PYMB_FRAME_INCOMPLETE (more bytes needed),
     * PYMB_FRAME_BAD_FUNCTION (only silence ends it), others impossible. */
    int (*reply_length)(const uint8_t *adu, int have, int expect);
    /* Receive one reply ADU into rsp[0..cap): its length, or -1 and errno,
     * having noted what came in fail and owed a quiet window if need be. */
    int (*receive)(pymb_line *line, const uint8_t *req, int req_len, int expect,
                   uint64_t sent_us, uint8_t *rsp, int cap, pymb_failure *fail);
    /* Check a received ADU against req: a pymb_frame_status (and *exc). */
    int (*check)(pymb_line *line, const uint8_t *req, int req_len, const uint8_t *rsp, int n,
                 int expect, int *exc);
    /* After a reply that failed its check: nonzero when what follows it
     * cannot be told from an answer (a quiet window is then owed). */
    int (*lost_step)(pymb_line *line);
    /* Open the line's descriptor: 0, or -1 and errno. node and service say
     * where, for a transport that opens its own socket (UDP); the others
     * let libmodbus open what their context names (pymbi_modbus_connect). */
    int (*connect)(pymb_line *line, const char *node, const char *service);
    /* Close what connect opened; the context stays and can connect again. */
    void (*close)(pymb_line *line);
};

extern const pymb_transport pymbi_transport_rtu;
extern const pymb_transport pymbi_transport_tcp;
extern const pymb_transport pymbi_transport_rtu_over_tcp;
extern const pymb_transport pymbi_transport_ascii;
extern const pymb_transport pymbi_transport_udp;

/* What every function taking a pymb_failure writes first, even when it then
 * refuses its arguments: nothing asked, nothing received. */
static inline void pymb_failure_reset(pymb_failure *fail)
{
    if (fail != NULL) {
        fail->function = -1;
        fail->address = -1;
        fail->count = -1;
        fail->frame = 0;
        fail->rsp_len = 0;
        fail->header = 0;
    }
}

/* pymb_request.c: a read plan the Python extension runs again and again
 * (pymb._native.link.RegisterPlan): pymb_read_plan()'s arguments held, and a
 * decode made ready (pymb_map_ready.h), or NULL, run once every request from
 * `start` on has its reply. Each run sets `done` (pymb_read_plan()'s, counted
 * from `start`) and `decoded` (1 when it decoded `then`). */
typedef struct {
    const pymb_plan_request *reqs;
    size_t n;
    uint32_t gap_us;
    uint16_t *regs;
    size_t nregs;
    const pymbi_map_job *then;
    size_t done;
    int decoded;
    pymb_line *line; /* pymbi_plan_go()'s line and failure record, set by the caller */
    pymb_failure *fail;
} pymbi_plan;

/* Run plan->reqs[start..n) as pymb_read_plan() does, then plan->then. */
int pymbi_plan_run(pymb_line *line, pymbi_plan *plan, size_t start, pymb_failure *fail);

/* pymbi_plan_run(plan->line, plan, 0, plan->fail): a steady poller's run as a
 * call of one argument (the extension's cheapest call). */
int pymbi_plan_go(pymbi_plan *plan);

/* TCP, UDP: the transaction id the line's next request gets (pymbi_line_tid),
 * and that id set (pymbi_line_set_tid): a connection lent by another master
 * (pymb log's polls) goes on with that master's ids, so that a late reply
 * to one of its requests is not taken for the answer to one of the line's. */
uint16_t pymbi_line_tid(const pymb_line *line);
void pymbi_line_set_tid(pymb_line *line, uint16_t tid);

/* pymb_line.c: clocks, waits and the quiet window. */
uint64_t pymbi_now_us(void);
uint64_t pymbi_timeout_us(modbus_t *ctx, int byte);
int pymbi_line_ok(const pymb_line *line);
int pymbi_wait_readable(pymb_line *line, int fd, uint64_t wait_us);
int pymbi_input_pending(const pymb_line *line);
int pymbi_drain_since(pymb_line *line, uint64_t last, uint64_t quiet_us, uint64_t max_us);
void pymbi_owe(pymb_line *line, int slave);
int pymbi_pay_owed(pymb_line *line);
uint64_t pymbi_quiet_window_us(pymb_line *line);
int pymbi_send_all(pymb_line *line, const uint8_t *b, size_t n);
ssize_t pymbi_read(pymb_line *line, int fd, uint8_t *buf, size_t n);
void pymbi_no_flush(pymb_line *line);
void pymbi_serial_flush(pymb_line *line); /* tcdrain: the request is on the wire */
void pymbi_note_reply(pymb_failure *fail, const uint8_t *rsp, int len, int frame);
int pymbi_modbus_connect(pymb_line *line, const char *node, const char *service);
void pymbi_modbus_close(pymb_line *line);
int pymbi_write_all(pymb_line *line, const uint8_t *b, size_t n);

/* pymb_ascii.c: the ASCII frame ([MB-SL] 2.5.2), for its tests and fuzzer.
 * ':', two hexadecimal characters per byte of address, PDU and LRC, CR LF. */
#define PYMB_ASCII_MAX_BYTES (1 + PYMB_MAX_PDU + 1)        /* address, PDU, LRC */
#define PYMB_ASCII_MAX_TEXT (1 + 2 * PYMB_ASCII_MAX_BYTES + 2) /* ':' ... CR LF */

/* The LRC of b[0..n): the two's complement of their sum, modulo 256. */
uint8_t pymbi_ascii_lrc(const uint8_t *b, size_t n);
/* The frame of b[0..n) (address + PDU) with its LRC into out[0..cap): its
 * length, or -1 when it does not fit or n is not 2..254. */
int pymbi_ascii_encode(const uint8_t *b, int n, uint8_t *out, int cap);

/* A receiver: bytes in, whole frames out. Zeroed: waiting for a ':'. */
typedef struct {
    int in_frame;  /* a ':' has started a frame */
    int cr;        /* its last character was CR */
    int bad;       /* it holds a character that is not a hexadecimal digit */
    int nhex;      /* hexadecimal digits so far */
    uint8_t out[PYMB_ASCII_MAX_BYTES];
} pymbi_ascii_rx;

/* Feed one character. Returns PYMB_FRAME_INCOMPLETE until a frame ends
 * (CR LF), then its bytes' count (address, PDU, LRC: 3 or more) with the
 * bytes in rx->out, or PYMB_FRAME_TOO_LONG (more bytes than any frame, said
 * at the first digit too many), PYMB_FRAME_BAD_TEXT (an odd number of
 * digits, a character that is no digit, CR not followed by LF: rx->out then
 * holds the bytes before the first such character) or PYMB_FRAME_BAD_LENGTH
 * (fewer than 3 bytes). A ':' starts a frame again wherever it comes;
 * characters outside a frame are ignored. The LRC is not checked here. */
int pymbi_ascii_feed(pymbi_ascii_rx *rx, uint8_t c);

/* The check of a decoded reply f[0..n) (address, PDU, LRC) against req
 * (address + PDU): a pymb_frame_status, PYMB_FRAME_BAD_CRC for a bad LRC. */
int pymbi_ascii_check(const uint8_t *req, int req_len, const uint8_t *f, int n, int *exc);

/* pymb_rtu.c: the RTU half that RTU over TCP shares. */
int pymbi_rtu_prepare(pymb_line *line, int slave);
int pymbi_rtu_reply_length(const uint8_t *adu, int have, int expect);
int pymbi_rtu_receive(pymb_line *line, const uint8_t *req, int req_len, int expect,
                      uint64_t sent_us, uint8_t *rsp, int cap, pymb_failure *fail);
int pymbi_rtu_check(pymb_line *line, const uint8_t *req, int req_len, const uint8_t *rsp, int n,
                    int expect, int *exc);
int pymbi_rtu_lost_step(pymb_line *line);

/* pymb_tcp.c: the MBAP half that UDP shares ([MB-TCP] 3.1.3; the framing,
 * the length rule and the reply check are pymb_frame.c's: pymb_master.h). */
int pymbi_mbap_build(pymb_line *line, const uint8_t *req, int req_len, uint8_t *adu, int cap);
int pymbi_mbap_reply_length(const uint8_t *adu, int have, int expect);
int pymbi_mbap_check(pymb_line *line, const uint8_t *req, int req_len, const uint8_t *rsp, int n,
                     int expect, int *exc);

#endif /* PYMB_INTERNAL_H */
