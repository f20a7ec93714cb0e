/* SPDX-License-Identifier: MIT */
/*
 * coolpro_read.c - read a CoolPro power supply's telemetry and identity from
 * C with libpymb's generic API: both reads in one pymb_read_plan call and
 * pymb_map_decode over a small compiled-in map of the device (devices.h).
 *
 *   make -C csrc                      # builds build/coolpro_read
 *   ./csrc/build/coolpro_read /dev/ttyUSB0 9600 40
 *   ./csrc/build/coolpro_read tcp:127.0.0.1:1502 0 40
 *
 * Prints one "name value" line a value.
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>

#include "devices.h"

int main(int argc, char **argv)
{
    double values[CP_VALUES];
    int64_t ints[CP_VALUES];
    pymb_failure fail;
    modbus_t *ctx;
    pymb_line *line;
    int slave, rc, i;

    if (argc != 4) {
        fprintf(stderr, "usage: %s PORT BAUD SLAVE (PORT: a serial device or tcp:HOST:PORT)\n",
                argv[0]);
        return 2;
    }
    slave = atoi(argv[3]);
    line = example_open(argv[1], atoi(argv[2]), 500, &ctx);
    if (line == NULL) {
        return 4;
    }
    rc = coolpro_read(line, slave, values, ints, &fail);
    if (rc == -1) {
        fprintf(stderr, "CoolPro %d on %s: %s (request for %d registers at %d)\n", slave,
                argv[1], pymb_strerror(errno), fail.count, fail.address);
    } else {
        for (i = 0; i < CP_VALUES; i++) {
            if (coolpro_entries[i].flags & PYMB_MAP_SCALED) {
                printf("%s %g\n", coolpro_names[i], values[i]);
            } else {
                printf("%s %" PRId64 "\n", coolpro_names[i], ints[i]);
            }
        }
    }
    example_close(line, ctx);
    return rc == -1 ? 3 : 0;
}
