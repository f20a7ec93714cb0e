/* SPDX-License-Identifier: MIT */
/*
 * example_peer.c - the device the examples read in `make check`: libmodbus's
 * own Modbus TCP server (modbus_receive + modbus_reply, not pymb) on
 * 127.0.0.1, a free port, serving
 *   - a sensor hub whose firmware lacks the last block: holding registers
 *     31..630 (so 631..730 answer exception 02), channel 3 offline in every
 *     block, channel 1 below zero, channel 2 without a humidity sensor;
 *   - a CoolPro's input registers 0..7 and 100..107, the worked values of
 *     its document.
 *
 *   example_peer N     prints "READY <port>", serves N connections one
 *                      after another, then exits (in any case within 60 s)
 */
#define _DEFAULT_SOURCE

#include <arpa/inet.h>
#include <errno.h>
#include <modbus.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

static uint16_t hub_raw(unsigned b, unsigned c)
{
    static const uint16_t plain[6] = {200, 450, 150, 101, 3300, 0xFFB5};
    if (c == 2) {
        return 0xFFFF; /* offline */
    }
    if (c == 0 && (b == 0 || b == 2)) {
        return b == 0 ? (0x8000u | 105u) : 0x8000u; /* -10.5 and -0 degC */
    }
    if (c == 1 && b == 1) {
        return 0x8000u; /* no humidity sensor (0.1 % unit) */
    }
    return (uint16_t)(plain[b] + (b < 2 ? c : 0));
}

int main(int argc, char **argv)
{
    static const uint16_t telemetry[8] = {0x5FB4, 0x0CB2, 0x5DC0, 0x0C80,
                                          0x64C8, 4464,   1,      0x8041};
    static const uint16_t identity[8] = {0x3039, 0, 2, 1, 0, 0, 0x5E00, 0x6A50};
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    struct sockaddr_in addr;
    socklen_t len = sizeof addr;
    modbus_mapping_t *map;
    modbus_t *ctx;
    int listener, n, served, one = 1;
    unsigned b, c;

    if (argc != 2 || (n = atoi(argv[1])) < 1) {
        fprintf(stderr, "usage: %s CONNECTIONS\n", argv[0]);
        return 2;
    }
    alarm(60);
    map = modbus_mapping_new_start_address(0, 0, 0, 0, 31, 600, 0, 108);
    ctx = modbus_new_tcp("127.0.0.1", 0);
    listener = socket(AF_INET, SOCK_STREAM, 0);
    if (map == NULL || ctx == NULL || listener < 0) {
        fprintf(stderr, "example_peer: %s\n", strerror(errno));
        return 1;
    }
    for (b = 0; b < 6; b++) {
        for (c = 0; c < 100; c++) {
            map->tab_registers[b * 100 + c] = hub_raw(b, c);
        }
    }
    memcpy(map->tab_input_registers, telemetry, sizeof telemetry);
    memcpy(map->tab_input_registers + 100, identity, sizeof identity);
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    setsockopt(listener, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(listener, (struct sockaddr *)&addr, sizeof addr) != 0 || listen(listener, 4) != 0 ||
        getsockname(listener, (struct sockaddr *)&addr, &len) != 0) {
        fprintf(stderr, "example_peer: %s\n", strerror(errno));
        return 1;
    }
    printf("READY %u\n", (unsigned)ntohs(addr.sin_port));
    fflush(stdout);
    for (served = 0; served < n; served++) {
        int s = accept(listener, NULL, NULL);
        if (s < 0) {
            fprintf(stderr, "example_peer: accept: %s\n", strerror(errno));
            return 1;
        }
        modbus_set_socket(ctx, s);
        for (;;) {
            int rc = modbus_receive(ctx, query);
            if (rc > 0) {
                modbus_reply(ctx, query, rc, map);
            } else if (rc == -1) {
                break; /* the client closed the connection */
            }
        }
        close(s);
    }
    close(listener);
    modbus_mapping_free(map);
    modbus_free(ctx);
    return 0;
}
