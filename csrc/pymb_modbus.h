/*
 * pymb_modbus.h - pymb's request path over libmodbus.
 *
 * libmodbus opens and configures the line (serial settings, RS485, RTS, TCP)
 * and moves frames (modbus_send_raw_request / modbus_receive_confirmation).
 * pymb builds every request and checks every reply itself, because
 * libmodbus 3.1.6
 *   - refuses RTU addresses above 247 (the sensor hub uses 248..255),
 *   - skips the CRC check of any reply whose address it does not expect,
 *   - never checks that a write's echo matches what was written,
 *   - never discards input before a request, so a late reply to an earlier
 *     request is taken as the answer to the next one.
 *
 * Every function here:
 *   - discards pending input before it sends (pymb_flush);
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
 *      broadcast: sent, not answered, returns 0.
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

#ifdef __cplusplus
}
#endif

#endif /* PYMB_MODBUS_H */
