/* SPDX-License-Identifier: MIT */
/*
 * hub_read.c - read every channel of a 100-channel sensor hub from C, with
 * pymb's sweep (6 requests, firmware fallback, busy retry) and decoders.
 *
 *   make -C csrc                      # builds build/hub_read
 *   ./csrc/build/hub_read /dev/ttyUSB0 9600 1
 *   ./csrc/build/hub_read /dev/pts/5 9600 250    # addresses 248..255 work too
 *
 * Link your own program the same way:
 *   cc -std=c99 my.c -Ipath/to/csrc path/to/csrc/build/libpymb.a \
 *      $(pkg-config --cflags --libs libmodbus) -lm
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "pymb_modbus.h"

static const char *const block_names[PYMB_HUB_BLOCKS] = {
    "temperature_c", "humidity_pct", "pressure_temperature_c", "pressure_kpa",
    "voltage_mv",    "rssi_dbm",     "temperature2_c",
};
static const char *const state_names[] = {"", "offline", "no sensor", "unsupported",
                                          "not read"};

int main(int argc, char **argv)
{
    uint16_t regs[PYMB_HUB_REGISTERS];
    double values[PYMB_HUB_REGISTERS];
    uint8_t states[PYMB_HUB_REGISTERS];
    pymb_span spans[16];
    pymb_hub_request rq;
    pymb_failure fail;
    modbus_t *ctx;
    pymb_line *line;
    int baud, slave, n, rc;
    unsigned b, c;

    if (argc != 4) {
        fprintf(stderr, "usage: %s PORT BAUD SLAVE\n", argv[0]);
        return 2;
    }
    baud = atoi(argv[2]);
    slave = atoi(argv[3]);
    ctx = modbus_new_rtu(argv[1], baud, 'N', 8, 1);
    if (ctx == NULL || modbus_connect(ctx) == -1) {
        fprintf(stderr, "cannot open %s: %s\n", argv[1], modbus_strerror(errno));
        modbus_free(ctx);
        return 4;
    }
    /* [NOTES]: the hub may take 500 ms plus the reply's own wire time. */
    modbus_set_response_timeout(ctx, 1, 0);
    modbus_set_byte_timeout(ctx, 0, 0);
    line = pymb_line_new(ctx, PYMB_FRAMING_RTU, pymb_rtu_silence_us(baud));
    if (line == NULL) {
        fprintf(stderr, "cannot set up %s: %s\n", argv[1], pymb_strerror(errno));
        modbus_close(ctx);
        modbus_free(ctx);
        return 4;
    }

    n = pymb_hub_plan_all(0, PYMB_HUB_CHANNELS, spans, 16);
    rq = (pymb_hub_request){
        .slave = slave,
        .channels = PYMB_HUB_CHANNELS,
        .spans = spans,
        .nspans = n,
        .options = {.busy_retries = 3, .busy_backoff_us = 20000},
        .regs = regs,
        .values = values,
        .states = states,
        .out_len = PYMB_HUB_REGISTERS,
    };
    rc = pymb_hub_read(line, &rq, &fail);
    if (rc == -1) {
        fprintf(stderr, "hub %d on %s: %s (request for %d registers at %d)\n", slave, argv[1],
                pymb_strerror(errno), fail.count, fail.address);
    } else {
        printf("channel");
        for (b = 0; b < PYMB_HUB_BLOCKS; b++) {
            printf(",%s", block_names[b]);
        }
        printf("\n");
        for (c = 0; c < PYMB_HUB_CHANNELS; c++) {
            printf("%u", c + 1);
            for (b = 0; b < PYMB_HUB_BLOCKS; b++) {
                unsigned i = b * PYMB_HUB_CHANNELS + c;
                if (states[i] == PYMB_VALUE) {
                    printf(",%g", values[i]);
                } else {
                    printf(",%s", state_names[states[i]]);
                }
            }
            printf("\n");
        }
    }
    pymb_line_free(line);
    modbus_close(ctx);
    modbus_free(ctx);
    return rc == -1 ? 3 : 0;
}
