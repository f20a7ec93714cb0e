/* SPDX-License-Identifier: MIT */
/*
 * hub_read.c - read every channel of a 100-channel sensor hub from C with
 * libpymb's generic API: the sweep's six requests in one pymb_read_plan call
 * (blocks the firmware lacks found by their exception 02 and skipped), and
 * pymb_map_decode over a small compiled-in map of the hub (devices.h).
 *
 *   make -C csrc                      # builds build/hub_read
 *   ./csrc/build/hub_read /dev/ttyUSB0 9600 1
 *   ./csrc/build/hub_read /dev/pts/5 9600 250    # addresses 248..255 work too
 *   ./csrc/build/hub_read tcp:127.0.0.1:1502 0 1 # through a Modbus TCP gateway
 *
 * Prints CSV: a header, then one line a channel, a value or its state.
 * Link your own program the same way:
 *   cc -std=c99 my.c $(pkg-config --cflags --libs pymb)
 */
#include <stdio.h>
#include <stdlib.h>

#include "devices.h"

static const char *const state_names[] = {"", "offline", "no sensor", "unsupported",
                                          "not read"};

int main(int argc, char **argv)
{
    uint16_t regs[HUB_REGISTERS] = {0};
    double values[HUB_REGISTERS];
    uint8_t states[HUB_REGISTERS];
    unsigned missing = 0, b, c;
    pymb_failure fail;
    modbus_t *ctx;
    pymb_line *line;
    int slave, rc;

    if (argc != 4) {
        fprintf(stderr, "usage: %s PORT BAUD SLAVE (PORT: a serial device or tcp:HOST:PORT)\n",
                argv[0]);
        return 2;
    }
    slave = atoi(argv[3]);
    /* [NOTES]: the hub may take 500 ms plus the reply's own wire time. */
    line = example_open(argv[1], atoi(argv[2]), 1000, &ctx);
    if (line == NULL) {
        return 4;
    }
    rc = hub_read(line, slave, regs, &missing, &fail);
    if (rc == -1) {
        fprintf(stderr, "hub %d on %s: %s (request for %d registers at %d)\n", slave, argv[1],
                pymb_strerror(errno), fail.count, fail.address);
    } else if (hub_decode(regs, missing, values, states) == -1) {
        fprintf(stderr, "hub_decode: %s\n", pymb_strerror(errno));
        rc = -1;
    } else {
        printf("channel");
        for (b = 0; b < HUB_BLOCKS; b++) {
            printf(",%s", hub_block_names[b]);
        }
        printf("\n");
        for (c = 0; c < HUB_CHANNELS; c++) {
            printf("%u", c + 1);
            for (b = 0; b < HUB_BLOCKS; b++) {
                unsigned i = b * HUB_CHANNELS + c;
                if (states[i] == PYMB_VALUE) {
                    printf(",%g", values[i]);
                } else {
                    printf(",%s", states[i] < 5 ? state_names[states[i]] : "?");
                }
            }
            printf("\n");
        }
    }
    example_close(line, ctx);
    return rc == -1 ? 3 : 0;
}
