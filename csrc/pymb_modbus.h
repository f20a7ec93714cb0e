/* SPDX-License-Identifier: MIT */
/*
 * pymb_modbus.h - pymb's request path over libmodbus.
 *
 * libmodbus opens and configures the line (serial settings, RS485, RTS, TCP
 * connect) and sends RTU frames (modbus_send_raw_request, which drives RTS).
 * pymb frames every TCP request itself (its own MBAP header with a
 * per-line transaction id: libmodbus 3.1.6 sends id 0 on raw requests),
 * receives every reply itself and checks every reply itself, because
 * libmodbus 3.1.6
 *   - refuses RTU addresses above 247 (the sensor hub uses 248..255),
 *   - skips the CRC check of any reply whose address it does not expect,
 *   - never checks that a write's echo matches what was written,
 *   - never checks a TCP reply's transaction id, protocol id or length,
 *   - cannot read a reply to a function code it does not know,
 *   - has no RTU-over-TCP transport (its issue #192).
 *
 * A pymb_line is opaque: pymb_line_new() makes one for an opened modbus_t
 * and a framing, and picks the transport (RTU, TCP, RTU over TCP, ASCII,
 * UDP) then; it
 * keeps the state a line needs between requests (the next MBAP transaction
 * id, a quiet window owed after a failure, the frame silence, an interrupt
 * hook), and nothing else in the library keeps state. The caller keeps
 * owning the modbus_t: pymb_line_free() frees the line only.
 *
 * Every request function:
 *   - RTU (and RTU over TCP): after a timeout, a bad frame or an interrupt,
 *     the line owes a quiet window: the *next* request to the same address
 *     first reads and drops input until the line has been silent for the
 *     response timeout counted from the failure, so the failed call itself
 *     returns within its timeout and a late reply is still never taken as a
 *     later answer. A request to another address does not wait (a late
 *     reply carries the failed request's address, which cannot pass as its
 *     answer): frames from the failed address are dropped from its receive
 *     until the window has passed, so a scan of silent addresses costs one
 *     timeout each;
 *   - TCP: a reply is accepted only when its transaction id, protocol id (0),
 *     length and unit id match the request; replies to older transactions
 *     are read and dropped while the wait goes on to the deadline. A whole
 *     frame that fails a check leaves the stream in step, so nothing is
 *     owed, unless bytes already wait behind it (its length lied); a frame
 *     cut short (a timeout or an interrupt mid-frame, an impossible MBAP
 *     header) owes the quiet window as over RTU;
 *   - ASCII: as RTU (the quiet window after a failure, late frames of the
 *     failed address dropped), frames delimited by ':' and CR LF, the LRC
 *     checked (a bad one is EMBBADCRC), a frame whose characters stop for
 *     longer than the byte timeout (PYMB_ASCII_CHAR_US when 0) dropped;
 *   - UDP: as TCP, but a datagram that is not the answer (another
 *     transaction id or unit, not one whole MBAP frame) is always dropped
 *     and the wait goes on, and an unanswered request is sent again
 *     (pymb_line_set_retries);
 *   - returns -1 with errno set on failure, as libmodbus does: ETIMEDOUT,
 *     EMBBADCRC, EMBBADSLAVE, EMBBADDATA (a malformed or mismatched reply),
 *     EINTR (the interrupt hook asked to stop), EINVAL for a bad argument,
 *     an exception errno (see pymb_exception_errno), or the OS's errno (EIO
 *     for an unplugged USB adapter, ECONNRESET for a closed TCP peer);
 *   - fills the optional pymb_failure with what was asked and what came back;
 *     it is reset first (function, address, count -1; frame, rsp_len and
 *     header 0), even when the arguments are refused.
 *
 * Not thread-safe per line (like libmodbus): one thread per pymb_line.
 */
#ifndef PYMB_MODBUS_H
#define PYMB_MODBUS_H

#include <modbus.h>

#include "pymb.h"

#ifdef __cplusplus
extern "C" {
#endif

/* [MB-SL] 2.1: after a broadcast the master waits this long (the "turnaround
 * delay", 100 to 200 ms there) before its next request. */
#define PYMB_BROADCAST_TURNAROUND_US 100000

/* Framings (transports) of a pymb_line. */
typedef enum {
    PYMB_FRAMING_RTU = 1,         /* address + PDU + CRC on a serial line */
    PYMB_FRAMING_TCP = 2,         /* [MB-TCP] MBAP header + PDU */
    PYMB_FRAMING_RTU_OVER_TCP = 3, /* RTU frames on a TCP socket (raw gateways) */
    PYMB_FRAMING_ASCII = 4,        /* [MB-SL] 2.5.2 ':', hex, LRC, CR LF on a serial line */
    PYMB_FRAMING_UDP = 5           /* one MBAP frame per UDP datagram */
} pymb_framing;

/* [MB-SL] 2.5.2.1: the longest gap between two characters of an ASCII
 * frame when the context's byte timeout is 0 (one second by default there). */
#define PYMB_ASCII_CHAR_US 1000000

/* The most a request is sent again (pymb_line_set_retries). */
#define PYMB_MAX_RETRIES 10

/* [MB-SL] 2.5.1.1: above 19200 baud t3.5 is fixed at 1750 us. */
#define PYMB_T35_FLOOR_US 1750

/* Longest wait in one poll while an interrupt hook is set: how soon a
 * signal that arrived in another thread is seen. */
#define PYMB_INTERRUPT_SLICE_US 50000

/* Exception codes 1..0x0B fail with errno MODBUS_ENOBASE + code, libmodbus's
 * EMBXILFUN..EMBXGTAR; codes 0x0C..0xFF, whose MODBUS_ENOBASE + code
 * libmodbus uses for its own errors, with PYMB_EXCEPTION_ENOBASE + code. */
/* PYMB_EXCEPTION_ENOBASE is defined in pymb.h (PYMB_ENOBASE, which equals
 * MODBUS_ENOBASE, + 0x100). */

/* The errno a request fails with when the device answers exception `code`
 * (1..255), as above. */
int pymb_exception_errno(int code);

/* The exception code (1..255) of an errno from pymb_exception_errno, or 0
 * when errnum is not one. */
int pymb_errno_exception(int errnum);

/* One line: a libmodbus context (opened by the caller, which also sets its
 * response and byte timeouts) and pymb's state for it. Opaque. */
typedef struct pymb_line pymb_line;

/* A line for `ctx` with `framing` and the frame silence `silence_us` that
 * ends an RTU reply of unknown length (t3.5, pymb_rtu_silence_us; 0:
 * PYMB_T35_FLOOR_US). No quiet window owed, no interrupt hook, no early-byte
 * check. Returns NULL and errno: EINVAL when ctx is NULL, framing is unknown
 * or ctx is not a context of that kind (RTU needs modbus_new_rtu's, TCP and
 * RTU over TCP modbus_new_tcp's), ENOMEM. */
pymb_line *pymb_line_new(modbus_t *ctx, pymb_framing framing, uint32_t silence_us);

/* Free a line made by pymb_line_new (NULL: nothing). The modbus_t is the
 * caller's: close and free it with libmodbus. */
void pymb_line_free(pymb_line *line);

/* The interrupt hook: called (with arg) when a wait is interrupted by a
 * signal and at least every PYMB_INTERRUPT_SLICE_US of waiting; nonzero
 * stops the request with EINTR (the line then owes a quiet window).
 * interrupted NULL (the default): a signal never stops a request. Returns
 * 0, or -1 (EINVAL) when line is NULL. */
int pymb_line_set_interrupt(pymb_line *line, int (*interrupted)(void *arg), void *arg);

/* I/O in place of the socket's own, for a line whose bytes are carried by
 * something else over the same descriptor (TLS: the callbacks encrypt and
 * decrypt). Each callback gets `arg`:
 *   read(arg, buf, n): up to n bytes into buf without blocking: their count,
 *     0 when the peer closed the stream, or a negative errno (-EAGAIN:
 *     nothing now; the line then waits until the descriptor is readable);
 *   write(arg, buf, n): all n bytes (within the response timeout): 0, or a
 *     negative errno;
 *   pending(arg): bytes that read would return now without the descriptor
 *     (already decrypted), so the line does not wait for them.
 * The descriptor (modbus_get_socket) is still the one waited on. */
typedef struct {
    int (*read)(void *arg, uint8_t *buf, int n);
    int (*write)(void *arg, const uint8_t *buf, int n);
    int (*pending)(void *arg);
    void *arg;
} pymb_line_io;

/* Give the line the I/O `io` (copied; every callback set), or the socket's
 * own again when io is NULL (the default). Returns 0, or -1 (EINVAL) when
 * line is NULL or a callback is missing. */
int pymb_line_set_io(pymb_line *line, const pymb_line_io *io);

/* RTU on a real line: one character's wire time in nanoseconds
 * (pymb_rtu_char_ns). Nonzero: bytes that arrive before the request can
 * have been answered (its own wire time plus 3.5 characters, less 5 %)
 * start no reply; they and the rest of their frame (until the frame silence)
 * are dropped, so a duplicated reply that follows its original at once is
 * never taken as the next answer. 0 (the default; right for a
 * pseudo-terminal, which has no wire time, and for TCP): no such check.
 * Returns 0, or -1 (EINVAL) when line is NULL. */
int pymb_line_set_char_ns(pymb_line *line, uint32_t char_ns);

/* Open the line's descriptor, as its transport does: RTU, ASCII, TCP and
 * RTU over TCP with modbus_connect(ctx) (node and service are not used: the
 * context names its port or host); UDP with a datagram socket connected to
 * node:service (a host name or address and a port), handed to its context
 * (a TCP one) with modbus_set_socket. Nothing happens when the context is
 * open already. A TCP connect waits for the context's response timeout (set
 * it first), ETIMEDOUT when it passes. Returns 0, or -1 and errno (EINVAL
 * when line is NULL, or node or service is NULL for UDP; the OS's or
 * libmodbus's errno). */
int pymb_line_connect(pymb_line *line, const char *node, const char *service);

/* Close what pymb_line_connect opened (modbus_close for the libmodbus
 * transports); the line and its context stay and can connect again. NULL
 * or a closed line: nothing. */
void pymb_line_close(pymb_line *line);

/* How many times a request unanswered within the response timeout is sent
 * again, 0..PYMB_MAX_RETRIES (0, the default: never). UDP only (its
 * datagrams may be lost; a resend carries the same transaction id, and a
 * reply to either send is the answer); the other transports ignore it.
 * Returns 0, or -1 (EINVAL) when line is NULL or retries is out of range. */
int pymb_line_set_retries(pymb_line *line, int retries);

/* Where a reply's PDU starts in the rsp that pymb_transact fills: 1 (RTU,
 * RTU over TCP, ASCII: after the address) or 7 (TCP, UDP: after the MBAP
 * header); -1
 * (EINVAL) when line is NULL. */
int pymb_line_header_length(const pymb_line *line);

/* t3.5 of [MB-SL] 2.5.1.1 at `baud` for 11-bit characters, in microseconds:
 * 3.5 x 11 bits / baud up to 19200 baud, PYMB_T35_FLOOR_US above. Returns 0
 * (EINVAL) for baud < 1. */
uint32_t pymb_rtu_silence_us(int baud);

/* One character's wire time at `baud` with `bits` bits per character
 * (start + data + parity + stop: 10 for 8N1, 11 for 8E1), in nanoseconds;
 * 0 (EINVAL) when baud < 1 or bits is not 7..12. */
uint32_t pymb_rtu_char_ns(int baud, int bits);

/* What a failed request asked and what came back, for error messages. */
typedef struct {
    int function;  /* function code of the request that failed */
    int address;   /* its first address (-1 when it has none) */
    int count;     /* its quantity (-1 when it has none) */
    int frame;     /* pymb_frame_status of the reply, 0 when not checked */
    int rsp_len;   /* bytes of the reply kept in rsp, 0 when none */
    int header;    /* bytes before the unit id's successor in rsp: 1 (RTU)
                    * or 7 (MBAP); rsp[header - 1] is the unit that answered */
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
} pymb_failure;

/* Discard pending input now (no waiting). Returns 0, or -1 and errno. */
int pymb_flush(pymb_line *line);

/* Read and drop input until the line has been silent for quiet_us, or until
 * max_us have passed in all; then flush. Returns the bytes dropped, or -1
 * and errno (EINVAL for a NULL or closed line, EINTR from the hook). */
int pymb_drain(pymb_line *line, uint32_t quiet_us, uint32_t max_us);

/* One request and its checked reply.
 *
 * req: address + PDU (function code, data), no CRC or MBAP: 2..254 bytes.
 *      Address 1..255 (RTU) or 0..255 (TCP unit id). Address 0 in RTU is a
 *      broadcast: sent, not answered; returns 0 once the frame has left and
 *      PYMB_BROADCAST_TURNAROUND_US has passed.
 * expect: the reply PDU's length (function code included) when the caller
 *      knows it, 0 when not. RTU needs it only for function codes whose reply
 *      length pymb_rtu_response_length cannot tell; without it such a reply
 *      ends at the line's frame silence (the byte timeout does not apply
 *      to it), at most PYMB_RTU_MAX_ADU bytes, and must have ended within the
 *      response timeout plus that silence. Then the CRC is checked over
 *      the whole frame. An exception reply is always accepted (2 bytes).
 * rsp: receives the whole reply as received (MBAP or address first; ASCII:
 *      its bytes decoded from their characters, address, PDU and LRC);
 *      rsp_cap >= MODBUS_MAX_ADU_LENGTH.
 * Returns the length of the reply's PDU, which starts at rsp + 7 (TCP, UDP)
 * or rsp + 1 (RTU, RTU over TCP, ASCII); -1 and errno on failure. */
int pymb_transact(pymb_line *line, const uint8_t *req, int req_len, int expect,
                  uint8_t *rsp, int rsp_cap, pymb_failure *fail);

/* Read nb registers with function 0x03 or 0x04 from slave (RTU 1..255, TCP
 * 0..255) into
 * dest[0..nb), in as many requests of at most 125 registers as it takes.
 * addr + nb <= 65536. Returns nb, or -1 and errno (dest may then hold the
 * chunks read before the failure). */
int pymb_read_registers(pymb_line *line, int function, int slave, int addr, int nb,
                        uint16_t *dest, pymb_failure *fail);

/* Read nb bits with function 0x01 or 0x02 into dest[0..nb), one byte (0/1)
 * per bit, in requests of at most 2000 bits. Returns nb, or -1 and errno. */
int pymb_read_bits(pymb_line *line, int function, int slave, int addr, int nb,
                   uint8_t *dest, pymb_failure *fail);

/* One register read of a prepared plan (pymb_read_plan). */
typedef struct {
    uint8_t function; /* 0x03 or 0x04 */
    uint8_t slave;    /* RTU 1..255, TCP 0..255 */
    uint16_t address; /* first register */
    uint16_t count;   /* 1..125 registers, address + count <= 65536 */
    uint32_t offset;  /* where its registers go: regs[offset..offset + count) */
} pymb_plan_request;

/* Run reqs[0..n) in order, each one request on the wire whose registers go
 * to regs + reqs[i].offset (so that a caller makes one call for a whole
 * read, with Python's GIL released for all of it). Before each request but
 * the first, gap_us of silence after the previous reply (a device's
 * turnaround or inter-request gap; the line's own frame silences and quiet
 * windows apply as to every request). Stops at the first failure.
 *
 * done (optional): set to the number of requests that succeeded, which on
 * failure is the index of the one that failed (regs then holds the
 * registers of reqs[0..*done)); on EINVAL for a bad argument, 0.
 * Every request is checked before any is sent: a function other than 0x03
 * or 0x04, a count outside 1..125, an address + count past 65536, a slave
 * the line cannot address, or an offset + count past nregs fails with
 * EINVAL and sends nothing. n = 0 succeeds at once.
 *
 * Returns 0, or -1 and errno as pymb_read_registers (an exception errno, so
 * the caller can tell a refused request from a lost line and go on with
 * reqs + *done + 1). */
int pymb_read_plan(pymb_line *line, const pymb_plan_request *reqs, size_t n, uint32_t gap_us,
                   uint16_t *regs, size_t nregs, size_t *done, pymb_failure *fail);

#ifdef __cplusplus
}
#endif

#endif /* PYMB_MODBUS_H */
