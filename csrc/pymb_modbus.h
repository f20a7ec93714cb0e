/*
 * pymb_modbus.h - pymb's request path over libmodbus.
 *
 * libmodbus opens and configures the line (serial settings, RS485, RTS, TCP),
 * sends frames (modbus_send_raw_request) and receives TCP replies. pymb
 * builds every request, receives RTU replies itself (in one read where the
 * bytes are there, where libmodbus makes three select + read steps), and
 * checks every reply itself, because libmodbus 3.1.6
 *   - refuses RTU addresses above 247 (the sensor hub uses 248..255),
 *   - skips the CRC check of any reply whose address it does not expect,
 *   - never checks that a write's echo matches what was written,
 *   - never discards input before a request, so a late reply to an earlier
 *     request is taken as the answer to the next one.
 *
 * Every function here:
 *   - discards pending input before it sends (pymb_flush; a zero-timeout
 *     poll first, so an empty line costs no flush);
 *   - after a timeout or a bad frame, reads and drops whatever arrives until
 *     the line has been silent for the response timeout (pymb_recover), so a
 *     late or stray reply can never be taken as the answer to a later request;
 *   - returns -1 with errno set on failure, as libmodbus does: ETIMEDOUT,
 *     EMBBADCRC, EMBBADSLAVE, EMBBADDATA, EMBXILFUN + (code - 1) for an
 *     exception response (MODBUS_ENOBASE + code), EMBBADEXC for an exception
 *     code above 0x0B, EINVAL for a bad argument, or the OS's errno (EIO for
 *     an unplugged USB adapter, ECONNRESET for a closed TCP peer);
 *   - fills the optional pymb_failure with what was asked and what came back.
 *
 * Not thread-safe per context (like libmodbus): one thread per modbus_t.
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

/* What a failed request asked and what came back, for error messages. */
typedef struct {
    int function;  /* function code of the request that failed */
    int address;   /* its first address (-1 when it has none) */
    int count;     /* its quantity (-1 when it has none) */
    int frame;     /* pymb_frame_status of the reply, 0 when not checked */
    int rsp_len;   /* bytes of the reply kept in rsp, 0 when none */
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
} pymb_failure;

/* Discard pending input (and unsent output). Returns 0 or -1. */
int pymb_flush(modbus_t *ctx);

/* Read and drop input until the line has been silent for quiet_us, or until
 * max_us have passed in all; then flush. Returns the bytes dropped, or -1. */
int pymb_drain(modbus_t *ctx, uint32_t quiet_us, uint32_t max_us);

/* pymb_drain with quiet = the context's response timeout and max = four
 * times that. errno is preserved, so it can follow a failed call. */
void pymb_recover(modbus_t *ctx);

/* One request and its checked reply.
 *
 * req: address + PDU (function code, data), no CRC or MBAP: 2..254 bytes.
 *      Address 1..255 (RTU) or 0..255 (TCP unit id). Address 0 in RTU is a
 *      broadcast: sent, not answered; returns 0 once the frame has left and
 *      PYMB_BROADCAST_TURNAROUND_US has passed.
 * rsp: receives the whole reply as received (MBAP or address first);
 *      rsp_cap >= MODBUS_MAX_ADU_LENGTH.
 * Returns the length of the reply's PDU, which starts at
 * rsp + modbus_get_header_length(ctx); -1 and errno on failure. */
int pymb_transact(modbus_t *ctx, const uint8_t *req, int req_len, uint8_t *rsp,
                  int rsp_cap, pymb_failure *fail);

/* Read nb registers with function 0x03 or 0x04 from slave (RTU 1..255, TCP
 * 0..255) into
 * dest[0..nb), in as many requests of at most 125 registers as it takes.
 * addr + nb <= 65536. Returns nb, or -1 and errno (dest may then hold the
 * chunks read before the failure). */
int pymb_read_registers(modbus_t *ctx, int function, int slave, int addr, int nb,
                        uint16_t *dest, pymb_failure *fail);

/* Read nb bits with function 0x01 or 0x02 into dest[0..nb), one byte (0/1)
 * per bit, in requests of at most 2000 bits. Returns nb, or -1 and errno. */
int pymb_read_bits(modbus_t *ctx, int function, int slave, int addr, int nb,
                   uint8_t *dest, pymb_failure *fail);

/* ------------------------------------------------------------------------ */
/* The sensor hub's sweep ([HUB] 3, [NOTES]).                               */

/* One read request: `count` registers from `address`. */
typedef struct {
    uint16_t address;
    uint16_t count;
} pymb_span;

typedef struct {
    int busy_retries;         /* re-sends after the hub's busy answer (exception
                               * 04, [HUB] 2.3.2.3) before giving up */
    uint32_t busy_backoff_us; /* wait before the first re-send; doubles each time */
} pymb_hub_options;

/* The fewest requests (at most 125 registers each) that read channels
 * 1..channels of every block not in skip_mask. Returns the number of spans
 * written to spans[0..cap), or -1 (EINVAL) when cap is too small. With all 7
 * blocks and 100 channels: 6 requests. */
int pymb_hub_plan_all(unsigned skip_mask, unsigned channels, pymb_span *spans, int cap);

/* A hub read, sweep and decode in one call (so that Python makes one call,
 * with the GIL released for the whole of it). */
typedef struct {
    /* in */
    int slave;                       /* 1..255 */
    unsigned channels;               /* 1..100 */
    const uint8_t *humidity_tenths;  /* `channels` bytes or NULL (all 0.1 %) */
    const uint8_t *wanted;           /* PYMB_HUB_BITMAP_BYTES or NULL (spans) */
    const pymb_span *spans;          /* the plan, inside 31..730 */
    int nspans;
    pymb_hub_options options;
    /* in and out: blocks known to be missing from the firmware; blocks found
     * missing (exception 02 on a read of that block alone) are added */
    unsigned unsupported;
    /* out */
    unsigned read_mask;              /* blocks whose requested registers were all read */
    uint16_t *regs;                  /* PYMB_HUB_REGISTERS raw registers */
    double *values;                  /* out_len >= 7 * channels, or NULL: no decode */
    uint8_t *states;
    size_t out_len;
} pymb_hub_request;

/* Execute rq->spans with function 0x03. A span answered with exception 02
 * is read again block by block (only the wanted registers of each block); a
 * block still answered 02 is marked unsupported and the sweep goes on, so
 * every block the firmware has is returned. The hub's busy answer (04) is
 * retried per rq->options. Then, unless rq->values is NULL, the registers are
 * decoded as pymb_hub_decode does.
 *
 * Returns 0, or -1 and errno: EMBXSFAIL when the hub stayed busy, or any
 * error of pymb_read_registers (timeout, bad frame, OS error). */
int pymb_hub_read(modbus_t *ctx, pymb_hub_request *rq, pymb_failure *fail);

#ifdef __cplusplus
}
#endif

#endif /* PYMB_MODBUS_H */
