/* SPDX-License-Identifier: MIT */
/*
 * pymb_decode.c - raw registers to engineering values, no allocation, no I/O.
 *
 * Divisions are by 10.0 and 1000.0 (not multiplications by 0.1 and 0.001) so
 * that every result is the correctly rounded double of the document's value:
 * 251 -> 25.1 exactly as Python's 251 / 10 gives it.
 */
#include <errno.h>
#include <math.h>

#include "pymb.h"

double pymb_sm_tenths(uint16_t raw)
{
    double magnitude = (double)(raw & 0x7FFFu) / 10.0;
    return (raw & 0x8000u) ? -magnitude : magnitude;
}

double pymb_milli(uint16_t raw)
{
    return (double)raw / 1000.0;
}

int pymb_u32_lo_hi(const uint16_t *regs, uint32_t *value)
{
    if (regs == NULL || value == NULL) {
        errno = EINVAL;
        return -1;
    }
    *value = ((uint32_t)regs[1] << 16) | regs[0];
    return 0;
}

static uint32_t u32_lo_hi(const uint16_t *regs)
{
    return ((uint32_t)regs[1] << 16) | regs[0];
}

int pymb_hub_decode_one(pymb_hub_block block, uint16_t raw, int humidity_tenths,
                        double *value)
{
    int state = PYMB_VALUE;
    double v = NAN;

    if ((int)block < 0 || (int)block >= PYMB_HUB_BLOCKS) {
        if (value != NULL) {
            *value = NAN;
        }
        errno = EINVAL;
        return -1;
    }
    if (raw == PYMB_HUB_OFFLINE) {
        state = PYMB_OFFLINE;
    } else {
        switch (block) {
        case PYMB_HUB_TEMPERATURE:
        case PYMB_HUB_PRESSURE_TEMPERATURE:
        case PYMB_HUB_TEMPERATURE2:
            v = pymb_sm_tenths(raw);
            break;
        case PYMB_HUB_HUMIDITY:
            if (humidity_tenths) {
                if (raw == PYMB_HUB_NO_HUMIDITY_TENTHS) {
                    state = PYMB_NO_SENSOR;
                } else {
                    v = (double)raw / 10.0;
                }
            } else if (raw == PYMB_HUB_NO_HUMIDITY_1PCT) {
                state = PYMB_NO_SENSOR;
            } else {
                v = (double)raw;
            }
            break;
        case PYMB_HUB_RSSI:
            v = (double)(int16_t)raw;
            break;
        default: /* pressure (kPa) and voltage (mV): unsigned as they are */
            v = (double)raw;
            break;
        }
    }
    if (value != NULL) {
        *value = v;
    }
    return state;
}

/* One block of one kind; the kind is fixed for the whole loop so that the
 * compiler can keep each loop free of the switch above. */
static void decode_tenths(const uint16_t *raw, unsigned n, double *v, uint8_t *st)
{
    unsigned c;
    for (c = 0; c < n; c++) {
        if (raw[c] == PYMB_HUB_OFFLINE) {
            v[c] = NAN;
            st[c] = PYMB_OFFLINE;
        } else {
            v[c] = pymb_sm_tenths(raw[c]);
            st[c] = PYMB_VALUE;
        }
    }
}

static void decode_unsigned(const uint16_t *raw, unsigned n, double *v, uint8_t *st)
{
    unsigned c;
    for (c = 0; c < n; c++) {
        if (raw[c] == PYMB_HUB_OFFLINE) {
            v[c] = NAN;
            st[c] = PYMB_OFFLINE;
        } else {
            v[c] = (double)raw[c];
            st[c] = PYMB_VALUE;
        }
    }
}

static void decode_signed(const uint16_t *raw, unsigned n, double *v, uint8_t *st)
{
    unsigned c;
    for (c = 0; c < n; c++) {
        if (raw[c] == PYMB_HUB_OFFLINE) {
            v[c] = NAN;
            st[c] = PYMB_OFFLINE;
        } else {
            v[c] = (double)(int16_t)raw[c];
            st[c] = PYMB_VALUE;
        }
    }
}

static void decode_humidity(const uint16_t *raw, unsigned n, const uint8_t *tenths,
                            double *v, uint8_t *st)
{
    unsigned c;
    for (c = 0; c < n; c++) {
        st[c] = (uint8_t)pymb_hub_decode_one(PYMB_HUB_HUMIDITY, raw[c],
                                             tenths == NULL || tenths[c], &v[c]);
    }
}

static void mark(unsigned n, uint8_t state, double *v, uint8_t *st)
{
    unsigned c;
    for (c = 0; c < n; c++) {
        v[c] = NAN;
        st[c] = state;
    }
}

int pymb_hub_decode(const pymb_hub_request *rq)
{
    const uint16_t *regs;
    const uint8_t *humidity_tenths, *wanted;
    unsigned b, c, channels, read_mask, unsupported_mask;
    double *values;
    uint8_t *states;

    if (rq == NULL || rq->regs == NULL || rq->values == NULL || rq->states == NULL ||
        rq->channels < 1 || rq->channels > PYMB_HUB_CHANNELS ||
        rq->out_len < (size_t)PYMB_HUB_BLOCKS * rq->channels) {
        errno = EINVAL;
        return -1;
    }
    regs = rq->regs;
    channels = rq->channels;
    humidity_tenths = rq->humidity_tenths;
    wanted = rq->wanted;
    read_mask = rq->read_mask;
    unsupported_mask = rq->unsupported;
    values = rq->values;
    states = rq->states;
    for (b = 0; b < PYMB_HUB_BLOCKS; b++) {
        const uint16_t *raw = regs + (size_t)b * PYMB_HUB_CHANNELS;
        double *v = values + (size_t)b * channels;
        uint8_t *st = states + (size_t)b * channels;

        if (!(read_mask & (1u << b))) {
            mark(channels, (unsupported_mask & (1u << b)) ? PYMB_UNSUPPORTED : PYMB_NOT_READ,
                 v, st);
            continue;
        }
        switch (b) {
        case PYMB_HUB_TEMPERATURE:
        case PYMB_HUB_PRESSURE_TEMPERATURE:
        case PYMB_HUB_TEMPERATURE2:
            decode_tenths(raw, channels, v, st);
            break;
        case PYMB_HUB_HUMIDITY:
            decode_humidity(raw, channels, humidity_tenths, v, st);
            break;
        case PYMB_HUB_RSSI:
            decode_signed(raw, channels, v, st);
            break;
        default:
            decode_unsigned(raw, channels, v, st);
            break;
        }
        if (wanted != NULL) {
            for (c = 0; c < channels; c++) {
                unsigned i = b * PYMB_HUB_CHANNELS + c;
                if (!(wanted[i / 8] & (1u << (i % 8)))) {
                    v[c] = NAN;
                    st[c] = PYMB_NOT_READ;
                }
            }
        }
    }
    return 0;
}

int pymb_coolpro_decode_telemetry(const uint16_t *regs, size_t nregs,
                                  pymb_coolpro_telemetry *out)
{
    if (regs == NULL || out == NULL || nregs != PYMB_COOLPRO_TELEMETRY_COUNT) {
        errno = EINVAL;
        return -1;
    }
    out->input_voltage_v = pymb_milli(regs[0]);
    out->input_current_a = pymb_milli(regs[1]);
    out->output_voltage_v = pymb_milli(regs[2]);
    out->output_current_a = pymb_milli(regs[3]);
    out->temperature_c = pymb_milli(regs[4]);
    out->uptime_s = u32_lo_hi(regs + 5);
    out->status = regs[7];
    return 0;
}

int pymb_coolpro_decode_identity(const uint16_t *regs, size_t nregs,
                                 pymb_coolpro_identity *out)
{
    if (regs == NULL || out == NULL || nregs != PYMB_COOLPRO_IDENTITY_COUNT) {
        errno = EINVAL;
        return -1;
    }
    out->serial_number = u32_lo_hi(regs + 0);
    out->hardware_revision = regs[2];
    out->firmware_major = regs[3];
    out->firmware_minor = regs[4];
    out->firmware_patch = regs[5];
    out->manufactured = u32_lo_hi(regs + 6);
    return 0;
}
