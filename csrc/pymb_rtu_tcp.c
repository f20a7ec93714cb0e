/* SPDX-License-Identifier: MIT */
/*
 * pymb_rtu_tcp.c - RTU frames on a TCP socket, as transparent serial servers
 * in "raw" mode carry them (libmodbus has no such transport: its issue
 * #192). pymb appends the CRC and sends; receiving and checking are RTU's.
 */
#include <string.h>

#include "pymb_internal.h"

static int rtu_tcp_build(pymb_line *line, const uint8_t *req, int req_len, uint8_t *adu,
                         int cap)
{
    (void)line;
    memcpy(adu, req, (size_t)req_len);
    return pymb_rtu_append_crc(adu, (size_t)req_len, (size_t)cap);
}

static int rtu_tcp_send(pymb_line *line, const uint8_t *adu, int len)
{
    return pymbi_send_all(line, adu, (size_t)len);
}

const pymb_transport pymbi_transport_rtu_over_tcp = {
    PYMB_FRAMING_RTU_OVER_TCP,
    PYMB_MBAP_LENGTH, /* modbus_new_tcp's context */
    1,
    2,
    1,
    1,
    pymbi_rtu_prepare,
    rtu_tcp_build,
    rtu_tcp_send,
    pymbi_no_flush,
    pymbi_rtu_reply_length,
    pymbi_rtu_receive,
    pymbi_rtu_check,
    pymbi_rtu_lost_step,
    pymbi_modbus_connect,
    pymbi_modbus_close,
};
