/* pymb bench: a plain libmodbus client, the software floor.
 *
 * usage: sweep PORT BAUD HUB_SLAVE FIRST COUNT CHANNELS KINDS CP_SLAVE CP_ADDRESS CP_COUNT
 *              K_OFF K_VAL
 * KINDS: one letter per block: S sign-magnitude tenths, H humidity 0.1 %,
 *        U unsigned, I signed 16-bit.
 * stdin: "sweep N" | "tele N" | "verify" | "tverify" | "quit"
 * stdout: "ok CPU_NS WALL_NS..." | "ok VALUES..." | "err MESSAGE"
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include <modbus.h>

#define MAX_REGS 1024
#define MAX_BATCH 100000

static uint16_t regs[MAX_REGS];
static double values[MAX_REGS];
static uint16_t tele[MAX_REGS];
static double tele_values[8];
static long long walls[MAX_BATCH];

static int hub_slave, first, count, channels, cp_slave, cp_address, cp_count, k_off, k_val;
static const char *kinds;

static long long wall_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static long long cpu_ns(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return ((long long)ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) * 1000000000LL +
           ((long long)ru.ru_utime.tv_usec + ru.ru_stime.tv_usec) * 1000LL;
}

static double tenths(uint16_t r)
{
    double m = (r & 0x7FFF) / 10.0;
    return (r & 0x8000) ? -m : m;
}

static void decode(void)
{
    int b, c;
    for (b = 0; kinds[b] != '\0'; b++) {
        const uint16_t *raw = regs + b * channels;
        double *v = values + b * channels;
        for (c = 0; c < channels; c++) {
            uint16_t r = raw[c];
            if (r == 0xFFFF) {
                v[c] = NAN;
                continue;
            }
            switch (kinds[b]) {
            case 'S':
                v[c] = tenths(r);
                break;
            case 'H':
                v[c] = r == 0x8000 ? NAN : r / 10.0;
                break;
            case 'I':
                v[c] = (int16_t)r;
                break;
            default:
                v[c] = r;
            }
        }
    }
}

static const char *sweep(modbus_t *ctx)
{
    int done, n;
    modbus_set_slave(ctx, hub_slave);
    for (done = 0; done < count; done += n) {
        n = count - done > MODBUS_MAX_READ_REGISTERS ? MODBUS_MAX_READ_REGISTERS : count - done;
        if (modbus_read_registers(ctx, first + done, n, regs + done) != n) {
            return modbus_strerror(errno);
        }
    }
    decode();
    if (regs[k_off] != 0xFFFF || !isnan(values[k_off]) || regs[k_val] == 0xFFFF ||
        isnan(values[k_val])) {
        return "canary registers do not hold what the simulator serves";
    }
    return NULL;
}

static const char *telemetry(modbus_t *ctx)
{
    int i;
    modbus_set_slave(ctx, cp_slave);
    if (modbus_read_input_registers(ctx, cp_address, cp_count, tele) != cp_count) {
        return modbus_strerror(errno);
    }
    for (i = 0; i < 5; i++) {
        tele_values[i] = tele[i] / 1000.0; /* milliunits */
    }
    tele_values[5] = (double)((uint32_t)tele[6] << 16 | tele[5]); /* low word first */
    tele_values[6] = tele[7];
    if (tele_values[0] <= 0.0) {
        return "telemetry reads no input voltage";
    }
    return NULL;
}

static void batch(modbus_t *ctx, int n, const char *(*op)(modbus_t *))
{
    long long c0, t;
    const char *err = NULL;
    int i;

    if (n < 1 || n > MAX_BATCH) {
        printf("err batch size %d out of range\n", n);
        return;
    }
    c0 = cpu_ns();
    for (i = 0; i < n && err == NULL; i++) {
        t = wall_ns();
        err = op(ctx);
        walls[i] = wall_ns() - t;
    }
    c0 = cpu_ns() - c0;
    if (err != NULL) {
        printf("err %s\n", err);
        return;
    }
    printf("ok %lld", c0);
    for (i = 0; i < n; i++) {
        printf(" %lld", walls[i]);
    }
    printf("\n");
}

static void print_u16(const uint16_t *v, int n)
{
    int i;
    printf("ok");
    for (i = 0; i < n; i++) {
        printf(" %u", (unsigned)v[i]);
    }
    printf("\n");
}

static void print_f64(const double *v, int n)
{
    int i;
    printf("ok");
    for (i = 0; i < n; i++) {
        printf(" %.17g", v[i]);
    }
    printf("\n");
}

int main(int argc, char **argv)
{
    char line[128];
    modbus_t *ctx;

    if (argc != 13) {
        fprintf(stderr, "usage: %s PORT BAUD HUB_SLAVE FIRST COUNT CHANNELS KINDS CP_SLAVE "
                        "CP_ADDRESS CP_COUNT K_OFF K_VAL\n", argv[0]);
        return 2;
    }
    hub_slave = atoi(argv[3]);
    first = atoi(argv[4]);
    count = atoi(argv[5]);
    channels = atoi(argv[6]);
    kinds = argv[7];
    cp_slave = atoi(argv[8]);
    cp_address = atoi(argv[9]);
    cp_count = atoi(argv[10]);
    k_off = atoi(argv[11]);
    k_val = atoi(argv[12]);
    if (count < 1 || count > MAX_REGS || channels < 1 ||
        (int)strlen(kinds) * channels != count || cp_count < 8 || cp_count > MAX_REGS ||
        k_off < 0 || k_off >= count || k_val < 0 || k_val >= count) {
        fprintf(stderr, "bad layout arguments\n");
        return 2;
    }
    ctx = modbus_new_rtu(argv[1], atoi(argv[2]), 'N', 8, 1);
    if (ctx == NULL || modbus_connect(ctx) == -1) {
        printf("err cannot open %s: %s\n", argv[1], modbus_strerror(errno));
        modbus_free(ctx);
        return 4;
    }
    /* Generous: the hub may take 500 ms plus the reply's own wire time. */
    modbus_set_response_timeout(ctx, 2, 0);
    printf("ready libmodbus %s\n", LIBMODBUS_VERSION_STRING);
    fflush(stdout);

    while (fgets(line, sizeof line, stdin) != NULL) {
        const char *err;
        int n = 0;
        if (sscanf(line, "sweep %d", &n) == 1) {
            batch(ctx, n, sweep);
        } else if (sscanf(line, "tele %d", &n) == 1) {
            batch(ctx, n, telemetry);
        } else if (strncmp(line, "verify", 6) == 0) {
            if ((err = sweep(ctx)) != NULL) {
                printf("err %s\n", err);
            } else {
                print_u16(regs, count);
                print_f64(values, count);
            }
        } else if (strncmp(line, "tverify", 7) == 0) {
            if ((err = telemetry(ctx)) != NULL) {
                printf("err %s\n", err);
            } else {
                print_u16(tele, cp_count);
                print_f64(tele_values, 7);
            }
        } else if (strncmp(line, "quit", 4) == 0) {
            break;
        } else {
            printf("err unknown command\n");
        }
        fflush(stdout);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
