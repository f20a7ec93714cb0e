/* SPDX-License-Identifier: MIT */
/*
 * sweep_compare.c - pymb's hub sweep (pymb_read_plan, devices.h) against the
 * same sweep written with plain libmodbus (6 x modbus_read_registers), both
 * decoded by pymb_map_decode with the hub's map, and pymb's CoolPro
 * telemetry read (pymb_read_registers) against modbus_read_input_registers,
 * both decoded with the CoolPro's map, interleaved
 * in one process on one line: medians of wall and CPU time per operation.
 * For C users weighing pymb's request path, and to tell pymb's C cost apart
 * from the Python interpreter's in `pymb bench`.
 *
 *   pymb simulate hub,dynamic=0 coolpro:40,gap=0 --any-speed   # prints /dev/pts/N
 *   ./csrc/build/sweep_compare /dev/pts/N [ROUNDS]
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/resource.h>
#include <time.h>

#include "devices.h"

#define PER_ROUND 40
#define TELE_PER_ROUND 100
#define MAX_ROUNDS 200
#define COOLPRO_SLAVE 40
#define TELEMETRY 7 /* the telemetry's values: the first 7 of coolpro_entries */

static double wall_now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec / 1e9;
}

static double cpu_now(void)
{
    struct rusage u;
    getrusage(RUSAGE_SELF, &u);
    return (double)(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           (double)(u.ru_utime.tv_usec + u.ru_stime.tv_usec) / 1e6;
}

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, by_value);
    return v[n / 2];
}

static void report(const char *what, const char *name, double wall[2][MAX_ROUNDS],
                   double cpu[2][MAX_ROUNDS], int rounds, int per, const char *port)
{
    double wl = median(wall[0], rounds), wp = median(wall[1], rounds);
    double cl = median(cpu[0], rounds), cp = median(cpu[1], rounds);
    printf("%s, medians of %d interleaved rounds x %d on %s\n", what, rounds, per, port);
    printf("  plain libmodbus      wall %6.0f us  CPU %5.1f us\n", wl, cl);
    printf("  %-20s wall %6.0f us  CPU %5.1f us  (%.2fx, %.2fx)\n", name, wp, cp, wp / wl,
           cp / cl);
}

/* The CoolPro at COOLPRO_SLAVE: its telemetry read both ways. Returns -1
 * (and says why) when there is no CoolPro on the line: the hub's figures
 * stand alone then. */
static int telemetry_rounds(pymb_line *line, modbus_t *ctx, pymb_failure *fail, int rounds,
                            double wall[2][MAX_ROUNDS], double cpu[2][MAX_ROUNDS])
{
    uint16_t regs[8];
    double values[TELEMETRY];
    uint8_t states[TELEMETRY];
    pymb_map_out out = {0};
    int r, k, i;

    out.values = values;
    out.states = states;
    out.len = TELEMETRY;
    for (r = 0; r < rounds; r++) {
        for (k = 0; k < 2; k++) {
            int use_pymb = (r + k) % 2; /* the order alternates */
            double t0 = 0, c0 = 0;
            for (i = 0; i < 2 * TELE_PER_ROUND; i++) { /* the first half warms up */
                int rc;
                if (i == TELE_PER_ROUND) {
                    t0 = wall_now();
                    c0 = cpu_now();
                }
                if (use_pymb) {
                    rc = pymb_read_registers(line, MODBUS_FC_READ_INPUT_REGISTERS,
                                             COOLPRO_SLAVE, 0, 8, regs, fail);
                } else {
                    modbus_set_slave(ctx, COOLPRO_SLAVE);
                    rc = modbus_read_input_registers(ctx, 0, 8, regs);
                }
                if (rc < 0 ||
                    pymb_map_decode(coolpro_entries, TELEMETRY, NULL, 0, regs, 8, &out) < 0) {
                    fprintf(stderr, "no CoolPro telemetry at address %d (%s): hub only\n",
                            COOLPRO_SLAVE, modbus_strerror(errno));
                    return -1;
                }
            }
            wall[use_pymb][r] = (wall_now() - t0) / TELE_PER_ROUND * 1e6;
            cpu[use_pymb][r] = (cpu_now() - c0) / TELE_PER_ROUND * 1e6;
        }
    }
    return 0;
}

int main(int argc, char **argv)
{
    static double wall[2][MAX_ROUNDS], cpu[2][MAX_ROUNDS];
    uint16_t regs[HUB_REGISTERS] = {0};
    double values[HUB_REGISTERS];
    uint8_t states[HUB_REGISTERS];
    unsigned missing = 0;
    pymb_failure fail;
    modbus_t *ctx;
    pymb_line *line;
    int rounds = argc > 2 ? atoi(argv[2]) : 30, r, k, i;

    if (argc < 2 || rounds < 1 || rounds > MAX_ROUNDS) {
        fprintf(stderr, "usage: %s PORT [ROUNDS (1..%d)]\n", argv[0], MAX_ROUNDS);
        return 2;
    }
    line = example_open(argv[1], 115200, 2000, &ctx);
    if (line == NULL) {
        return 4;
    }

    for (r = 0; r < rounds; r++) {
        for (k = 0; k < 2; k++) {
            int use_pymb = (r + k) % 2; /* the order alternates */
            double t0 = 0, c0 = 0;
            for (i = 0; i < 2 * PER_ROUND; i++) { /* the first half warms up */
                if (i == PER_ROUND) {
                    t0 = wall_now();
                    c0 = cpu_now();
                }
                if (use_pymb) {
                    if (hub_read(line, 1, regs, &missing, &fail) == -1) {
                        fprintf(stderr, "hub_read: %s\n", pymb_strerror(errno));
                        return 3;
                    }
                } else {
                    int done, n;
                    modbus_set_slave(ctx, 1);
                    for (done = 0; done < HUB_REGISTERS; done += n) {
                        n = HUB_REGISTERS - done > 125 ? 125 : HUB_REGISTERS - done;
                        if (modbus_read_registers(ctx, HUB_FIRST + done, n, regs + done) != n) {
                            fprintf(stderr, "modbus_read_registers: %s\n",
                                    modbus_strerror(errno));
                            return 3;
                        }
                    }
                }
                hub_decode(regs, missing, values, states);
            }
            wall[use_pymb][r] = (wall_now() - t0) / PER_ROUND * 1e6;
            cpu[use_pymb][r] = (cpu_now() - c0) / PER_ROUND * 1e6;
        }
    }
    report("hub sweep", "pymb_read_plan", wall, cpu, rounds, PER_ROUND, argv[1]);
    if (telemetry_rounds(line, ctx, &fail, rounds, wall, cpu) == 0) {
        report("CoolPro telemetry (8 input registers, decoded)",
               "pymb_read_registers", wall, cpu, rounds, TELE_PER_ROUND, argv[1]);
    }
    example_close(line, ctx);
    return 0;
}
