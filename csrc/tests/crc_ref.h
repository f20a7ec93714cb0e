/* SPDX-License-Identifier: MIT */
/*
 * crc_ref.h - the tests' own CRC-16/MODBUS, bit by bit straight from [MB-SL]
 * 6.2.2, apart from the library's table-driven pymb_crc16.
 */
#ifndef PYMB_TESTS_CRC_REF_H
#define PYMB_TESTS_CRC_REF_H

#include <stddef.h>
#include <stdint.h>

static uint16_t crc_bitwise(const uint8_t *p, size_t n)
{
    uint16_t crc = 0xFFFF;
    size_t i;
    int b;
    for (i = 0; i < n; i++) {
        crc ^= p[i];
        for (b = 0; b < 8; b++) {
            crc = (crc & 1u) ? (uint16_t)((crc >> 1) ^ 0xA001u) : (uint16_t)(crc >> 1);
        }
    }
    return crc;
}

#endif
