/*
 * libmodbus_server.c - an independent Modbus server for pymb's tests, built
 * by the test itself (tests/client/test_client_peers.py) with Debian's libmodbus:
 *
 *   libmodbus_server tcp            Modbus TCP on 127.0.0.1, a free port
 *   libmodbus_server rtu            Modbus RTU on a new pseudo-terminal
 *   libmodbus_server rtu-over-tcp   RTU frames on TCP (a "raw" gateway): the
 *                                   RTU backend of libmodbus on an accepted
 *                                   socket (modbus_set_socket)
 *
 * Prints "READY <port or pty path>" once it listens, then answers requests
 * (modbus_receive + modbus_reply) from a mapping of 1000 coils, inputs and
 * registers, holding register i = i * 3 and input register i = 40000 + i,
 * as slave/unit 17, until killed. Unknown function codes get libmodbus's
 * exception 01.
 */
#define _XOPEN_SOURCE 700
#define _DEFAULT_SOURCE

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <modbus.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#define UNIT 17

static modbus_mapping_t *new_mapping(void)
{
    modbus_mapping_t *m = modbus_mapping_new(1000, 1000, 1000, 1000);
    int i;
    if (m == NULL) {
        exit(3);
    }
    for (i = 0; i < 1000; i++) {
        m->tab_registers[i] = (uint16_t)(i * 3);
        m->tab_input_registers[i] = (uint16_t)(40000 + i);
        m->tab_bits[i] = (uint8_t)(i % 3 == 0);
        m->tab_input_bits[i] = (uint8_t)(i % 2);
    }
    return m;
}

static void serve(modbus_t *ctx, modbus_mapping_t *m)
{
    uint8_t q[MODBUS_MAX_ADU_LENGTH];
    for (;;) {
        int n = modbus_receive(ctx, q);
        if (n > 0) {
            modbus_reply(ctx, q, n, m);
        } else if (n == -1 && errno != EMBBADCRC && errno != EMBBADDATA && errno != ETIMEDOUT) {
            return; /* the client went away */
        }
    }
}

/* A listening socket on 127.0.0.1 and a free port, printed. */
static int listen_any(void)
{
    struct sockaddr_in a;
    socklen_t len = sizeof a;
    int one = 1, s = socket(AF_INET, SOCK_STREAM, 0);

    memset(&a, 0, sizeof a);
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    setsockopt(s, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (s < 0 || bind(s, (struct sockaddr *)&a, sizeof a) || listen(s, 4) ||
        getsockname(s, (struct sockaddr *)&a, &len)) {
        perror("listen");
        exit(2);
    }
    printf("READY %d\n", ntohs(a.sin_port));
    fflush(stdout);
    return s;
}

int main(int argc, char **argv)
{
    modbus_mapping_t *m = new_mapping();
    modbus_t *ctx;

    setvbuf(stdout, NULL, _IOLBF, 0);
    if (argc == 2 && strcmp(argv[1], "rtu") == 0) {
        struct termios tio;
        int fd = posix_openpt(O_RDWR | O_NOCTTY);
        if (fd < 0 || grantpt(fd) || unlockpt(fd) || tcgetattr(fd, &tio)) {
            perror("pty");
            return 2;
        }
        cfmakeraw(&tio);
        tcsetattr(fd, TCSANOW, &tio);
        ctx = modbus_new_rtu("/dev/null", 115200, 'N', 8, 1);
        modbus_set_socket(ctx, fd);
        modbus_set_slave(ctx, UNIT);
        printf("READY %s\n", ptsname(fd));
        fflush(stdout);
        serve(ctx, m);
        return 0;
    }
    if (argc == 2 && (strcmp(argv[1], "tcp") == 0 || strcmp(argv[1], "rtu-over-tcp") == 0)) {
        int rtu = strcmp(argv[1], "rtu-over-tcp") == 0;
        int s = listen_any();
        for (;;) {
            int c = accept(s, NULL, NULL);
            if (c < 0) {
                continue;
            }
            ctx = rtu ? modbus_new_rtu("/dev/null", 115200, 'N', 8, 1)
                      : modbus_new_tcp("127.0.0.1", 502);
            modbus_set_socket(ctx, c);
            modbus_set_slave(ctx, UNIT);
            serve(ctx, m);
            close(c);
            modbus_free(ctx);
        }
    }
    fprintf(stderr, "usage: %s tcp|rtu|rtu-over-tcp\n", argv[0]);
    return 2;
}
