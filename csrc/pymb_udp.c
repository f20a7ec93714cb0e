/* SPDX-License-Identifier: MIT */
/*
 * pymb_udp.c - Modbus over UDP: one MBAP frame ([MB-TCP] 3.1.3) per
 * datagram, on a datagram socket this transport opens and connects itself
 * (libmodbus has no UDP transport; its TCP context only keeps the timeouts
 * and, through modbus_set_socket, the descriptor). A datagram is a whole
 * frame or nothing, so nothing is ever out of step: a reply is taken only
 * when its transaction id, protocol id, length and unit id match the
 * request; any other datagram (a late reply, another unit's, garbage) is
 * dropped and the wait goes on. A request unanswered within the response
 * timeout is sent again, with the same transaction id (a reply to either
 * send is the answer), line->retries times.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "pymb_internal.h"
#include "pymb_master.h"

/* Datagrams waiting before a request are old: dropped. */
static int udp_prepare(pymb_line *line, int slave)
{
    uint8_t junk[PYMB_MBAP_LENGTH + PYMB_MAX_PDU];
    int fd = modbus_get_socket(line->ctx), i;

    (void)slave;
    line->owed = 0;
    for (i = 0; i < 1000 && recv(fd, junk, sizeof junk, MSG_DONTWAIT) >= 0; i++) {
    }
    return 0;
}

static int udp_send(pymb_line *line, const uint8_t *adu, int len)
{
    for (;;) {
        ssize_t k = send(modbus_get_socket(line->ctx), adu, (size_t)len, MSG_NOSIGNAL);
        if (k == len) {
            return 0;
        }
        if (k < 0 && errno == EINTR) {
            continue;
        }
        if (k >= 0) {
            errno = EMSGSIZE;
        }
        return -1;
    }
}

static int udp_receive(pymb_line *line, const uint8_t *req, int req_len, int expect,
                       uint64_t sent_us, uint8_t *rsp, int cap, pymb_failure *fail)
{
    int fd = modbus_get_socket(line->ctx), sends = 1;
    uint64_t timeout = pymbi_timeout_us(line->ctx, 0), deadline = sent_us + timeout;

    for (;;) {
        uint64_t now = pymbi_now_us();
        ssize_t k;
        int rc;

        if (now >= deadline) {
            uint8_t adu[PYMB_MBAP_LENGTH + PYMB_MAX_PDU];
            int len;

            if (sends > line->retries) {
                errno = ETIMEDOUT;
                return -1;
            }
            len = pymbi_mbap_frame(line->tid, req[0], req + 1, (size_t)req_len - 1, adu);
            if (udp_send(line, adu, len) < 0) {
                return -1;
            }
            sends++;
            deadline = pymbi_now_us() + timeout;
            continue;
        }
        rc = pymbi_wait_readable(line, fd, deadline - now);
        if (rc < 0) {
            return -1;
        }
        if (rc == 0) {
            continue;
        }
        k = recv(fd, rsp, (size_t)cap, MSG_TRUNC);
        if (k < 0) {
            if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) {
                continue;
            }
            return -1; /* ECONNREFUSED: nothing listens there (an ICMP answer) */
        }
        /* Not one whole MBAP frame, a reply to another request or from
         * another unit: not an answer, dropped (a timeout shows the last). */
        if (k > cap || pymbi_mbap_reply_length(rsp, (int)k, expect) != (int)k) {
            pymbi_note_reply(fail, rsp, k > cap ? cap : (int)k, PYMB_FRAME_BAD_HEADER);
            continue;
        }
        if (((unsigned)rsp[0] << 8 | rsp[1]) != line->tid) {
            pymbi_note_reply(fail, rsp, (int)k, PYMB_FRAME_BAD_TID);
            continue;
        }
        if (rsp[PYMB_MBAP_LENGTH - 1] != req[0]) {
            pymbi_note_reply(fail, rsp, (int)k, PYMB_FRAME_BAD_SLAVE);
            continue;
        }
        return (int)k;
    }
}

/* Datagrams never leave the line out of step. */
static int udp_lost_step(pymb_line *line)
{
    (void)line;
    return 0;
}

/* A datagram socket connected to node:service (the first address that
 * takes it), handed to the context. */
static int udp_connect(pymb_line *line, const char *node, const char *service)
{
    struct addrinfo hints, *res = NULL, *ai;
    int fd = -1, rc, err = EHOSTUNREACH;

    if (node == NULL || service == NULL) {
        errno = EINVAL;
        return -1;
    }
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_DGRAM;
    rc = getaddrinfo(node, service, &hints, &res);
    if (rc != 0) {
        errno = rc == EAI_SYSTEM ? errno : EHOSTUNREACH;
        return -1;
    }
    for (ai = res; ai != NULL; ai = ai->ai_next) {
        fd = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
        if (fd < 0) {
            err = errno;
            continue;
        }
        if (fcntl(fd, F_SETFD, FD_CLOEXEC) == 0 && connect(fd, ai->ai_addr, ai->ai_addrlen) == 0) {
            break;
        }
        err = errno;
        close(fd);
        fd = -1;
    }
    freeaddrinfo(res);
    if (fd < 0) {
        errno = err;
        return -1;
    }
    if (modbus_set_socket(line->ctx, fd) == -1) {
        err = errno;
        close(fd);
        errno = err;
        return -1;
    }
    return 0;
}

static void udp_close(pymb_line *line)
{
    int fd = modbus_get_socket(line->ctx);

    if (fd >= 0) {
        close(fd);
        modbus_set_socket(line->ctx, -1);
    }
}

const pymb_transport pymbi_transport_udp = {
    PYMB_FRAMING_UDP,
    PYMB_MBAP_LENGTH, /* modbus_new_tcp's context */
    PYMB_MBAP_LENGTH,
    0,
    0,
    0,
    udp_prepare,
    pymbi_mbap_build,
    udp_send,
    pymbi_no_flush,
    pymbi_mbap_reply_length,
    udp_receive,
    pymbi_mbap_check,
    udp_lost_step,
    udp_connect,
    udp_close,
};
