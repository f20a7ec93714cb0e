/* SPDX-License-Identifier: MIT */
/*
 * pymb_map.c - the table-driven decoder of device maps (pymb_map.h).
 *
 * Every entry is checked before anything is written, so a bad table fails
 * whole; the data itself never fails (markers, NaN and invalid text are
 * states). Scale: a decimal power 10^-k divides by 10^k (exact doubles up to
 * 1e22), so -1896 with scale 0.1 gives the double nearest -189.6 ([MAP] 3).
 */
#include <errno.h>
#include <math.h>
#include <string.h>

#include "pymb.h"
#include "pymb_map_ready.h"

/* Registers each fixed-width type takes; 0: from the entry's count. */
static const uint8_t type_registers[PYMB_MAP_TYPES] = {
    1, 0, 0,    /* bool, bit, bits (bit and bits: 1, 2 or 4) */
    1, 1, 1, 1, /* u8_hi u8_lo i8_hi i8_lo */
    1, 1, 2, 2, 4, 4, /* u16 i16 u32 i32 u64 i64 */
    1, 2, 4,    /* f16 f32 f64 */
    1,          /* sm16 */
    0, 0        /* string, raw */
};

/* 10^0 .. 10^22: every one an exact double. */
static const double pow10_exact[23] = {
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11,
    1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22
};

int pymb_map_order(const char *letters, int nbytes, uint8_t *perm)
{
    int k, nregs;
    size_t len;
    unsigned seen = 0;

    if (letters == NULL || perm == NULL || (nbytes != 2 && nbytes != 4 && nbytes != 8)) {
        errno = EINVAL;
        return -1;
    }
    nregs = nbytes / 2;
    len = strlen(letters);
    if (strcmp(letters, "ABCD") == 0 || strcmp(letters, "CDAB") == 0 ||
        strcmp(letters, "BADC") == 0 || strcmp(letters, "DCBA") == 0) {
        int reverse_regs = letters[0] == 'C' || letters[0] == 'D';
        int swap = letters[0] == 'B' || letters[0] == 'D';
        for (k = 0; k < nbytes; k++) {
            int reg = k / 2, byte = k % 2;
            int wreg = reverse_regs ? nregs - 1 - reg : reg;
            perm[k] = (uint8_t)(2 * wreg + (swap ? 1 - byte : byte));
        }
        return 0;
    }
    if (len != (size_t)nbytes) {
        errno = EINVAL;
        return -1;
    }
    /* letters[j] is the value byte that arrives at position j. */
    for (k = 0; k < nbytes; k++) {
        int letter = letters[k] - 'A';
        if (letter < 0 || letter >= nbytes || (seen & (1u << letter))) {
            errno = EINVAL;
            return -1;
        }
        seen |= 1u << letter;
        perm[letter] = (uint8_t)k;
    }
    return 0;
}

static int entry_ok(const pymb_map_entry *e, size_t nmarkers, size_t nregs,
                    const pymb_map_out *out)
{
    uint64_t last, nbytes, per;
    unsigned k, seen = 0;

    if (e->type >= PYMB_MAP_TYPES || e->channels < 1 || e->count < 1) {
        return 0;
    }
    if (type_registers[e->type] != 0 && e->count != type_registers[e->type]) {
        return 0;
    }
    if ((e->type == PYMB_MAP_BIT || e->type == PYMB_MAP_BITS) && e->count != 1 &&
        e->count != 2 && e->count != 4) {
        return 0;
    }
    last = (uint64_t)e->first + (uint64_t)(e->channels - 1) * e->stride + e->count;
    if (last > nregs || (uint64_t)e->out + e->channels > out->len) {
        return 0;
    }
    if ((size_t)e->first_marker + e->nmarkers > nmarkers || e->decimals > 22) {
        return 0;
    }
    if (e->type == PYMB_MAP_BIT && e->bit >= 16u * e->count) {
        return 0;
    }
    if (e->type == PYMB_MAP_BITS &&
        (e->width < 1 || e->width > 64 || (unsigned)e->bit + e->width > 16u * e->count)) {
        return 0;
    }
    if (e->flags & PYMB_MAP_SCALE_FROM) {
        if (e->type == PYMB_MAP_BOOL || e->type == PYMB_MAP_BIT || e->type == PYMB_MAP_STRING ||
            e->type == PYMB_MAP_RAW || (e->aux & ~PYMB_MAP_SF_SWAPPED) >= nregs) {
            return 0;
        }
    }
    if (e->flags & PYMB_MAP_MASKED) {
        if (e->nmarkers < 1 || e->type == PYMB_MAP_BOOL || e->type == PYMB_MAP_BIT ||
            e->type == PYMB_MAP_STRING || e->type == PYMB_MAP_RAW || e->type == PYMB_MAP_F16 ||
            e->type == PYMB_MAP_F32 || e->type == PYMB_MAP_F64) {
            return 0;
        }
    }
    if (e->type == PYMB_MAP_STRING) {
        if ((e->flags & PYMB_MAP_HIGH_BYTE) && (e->flags & PYMB_MAP_LOW_BYTE)) {
            return 0;
        }
        per = (e->flags & (PYMB_MAP_HIGH_BYTE | PYMB_MAP_LOW_BYTE)) ? e->count : 2u * e->count;
        if (out->text == NULL || (uint64_t)e->aux + per * e->channels > out->text_len) {
            return 0;
        }
    } else if (e->type != PYMB_MAP_BOOL && e->type != PYMB_MAP_RAW) {
        nbytes = 2u * e->count;
        for (k = 0; k < nbytes; k++) {
            if (e->order[k] >= nbytes || (seen & (1u << e->order[k]))) {
                return 0;
            }
            seen |= 1u << e->order[k];
        }
    }
    return 1;
}

/* The value's bits, most significant byte first, as the order says. */
static uint64_t pattern(const uint16_t *r, const pymb_map_entry *e)
{
    uint8_t wire[PYMB_MAP_MAX_BYTES];
    unsigned i, n = 2u * e->count;
    uint64_t u = 0;

    for (i = 0; i < e->count; i++) {
        wire[2 * i] = (uint8_t)(r[i] >> 8);
        wire[2 * i + 1] = (uint8_t)(r[i] & 0xFFu);
    }
    for (i = 0; i < n; i++) {
        u = u << 8 | wire[e->order[i]];
    }
    return u;
}

static int64_t sign_extend(uint64_t u, unsigned bits)
{
    if (bits < 64 && ((u >> (bits - 1)) & 1u)) {
        u |= ~(uint64_t)0 << bits;
    }
    if (u >> 63) {
        return -(int64_t)(~u) - 1;
    }
    return (int64_t)u;
}

static double half_to_double(uint16_t h)
{
    int exp = (h >> 10) & 0x1F;
    unsigned frac = h & 0x3FFu;
    double v;

    if (exp == 0) {
        v = ldexp((double)frac, -24);
    } else if (exp == 31) {
        v = frac ? NAN : INFINITY;
    } else {
        v = ldexp((double)(frac + 1024u), exp - 25);
    }
    return (h & 0x8000u) ? -v : v;
}

/* The state markers give a raw value: the first that matches, or PYMB_VALUE.
 * A PYMB_MAP_MARKER_MASK entry is the care mask of the marker after it. */
static inline uint8_t marker_state(const pymb_map_marker *mk, unsigned n, uint64_t raw)
{
    uint64_t care = ~(uint64_t)0;
    unsigned m;

    for (m = 0; m < n; m++) {
        if (mk[m].state == PYMB_MAP_MARKER_MASK) {
            care = mk[m].raw;
            continue;
        }
        if ((raw & care) == mk[m].raw) {
            return mk[m].state;
        }
        care = ~(uint64_t)0;
    }
    return PYMB_VALUE;
}

/* The scale factor of a PYMB_MAP_SCALE_FROM entry: 1 with *sf set, or 0 when
 * it is not implemented or out of range. */
static int scale_factor(const pymb_map_entry *e, const uint16_t *regs, int *sf)
{
    uint16_t w = regs[e->aux & ~PYMB_MAP_SF_SWAPPED];
    int v;

    if (e->aux & PYMB_MAP_SF_SWAPPED) {
        w = (uint16_t)(w << 8 | w >> 8);
    }
    v = (int)(int16_t)w;
    if (v < PYMB_MAP_SF_MIN || v > PYMB_MAP_SF_MAX) {
        return 0;
    }
    *sf = v;
    return 1;
}

static double apply(const pymb_map_entry *e, double v, int negative, int sf)
{
    if (e->flags & PYMB_MAP_SCALE_FROM) {
        v = sf < 0 ? v / pow10_exact[-sf] : v * pow10_exact[sf];
    } else if (e->decimals) {
        v = v / pow10_exact[e->decimals];
    } else if (e->flags & PYMB_MAP_SCALED) {
        v = v * e->scale;
    }
    if (negative) {
        v = -v;
    }
    if (e->flags & PYMB_MAP_OFFSET) {
        v = v + e->offset;
    }
    return v;
}

static void text(const uint16_t *r, const pymb_map_entry *e, uint8_t *dst, int64_t *len,
                 uint8_t *state)
{
    unsigned i, n = 0, end;
    int swap = (e->flags & PYMB_MAP_SWAP) != 0;

    for (i = 0; i < e->count; i++) {
        uint8_t hi = (uint8_t)(r[i] >> 8), lo = (uint8_t)(r[i] & 0xFFu);
        if (swap) {
            uint8_t t = hi;
            hi = lo;
            lo = t;
        }
        if (e->flags & PYMB_MAP_HIGH_BYTE) {
            dst[n++] = hi;
        } else if (e->flags & PYMB_MAP_LOW_BYTE) {
            dst[n++] = lo;
        } else {
            dst[n++] = hi;
            dst[n++] = lo;
        }
    }
    for (end = 0; end < n && dst[end] != 0; end++) {
        if ((e->flags & PYMB_MAP_ASCII) && dst[end] > 0x7F) {
            *state = PYMB_MAP_INVALID_TEXT;
        }
    }
    *len = end;
}

/* One channel: its registers regs + reg_index, its slot i. */
static void decode_one(const pymb_map_entry *e, const pymb_map_marker *mk, const uint16_t *regs,
                       size_t reg_index, size_t i, unsigned channel, const pymb_map_out *out)
{
    const uint16_t *r = regs + reg_index;
    uint64_t u, raw;
    unsigned bits = 16u * e->count, nmk = e->nmarkers;
    int64_t iv = 0;
    double v = NAN;
    uint8_t state = PYMB_VALUE;
    int sf = 0;

    switch (e->type) {
    case PYMB_MAP_BOOL:
        iv = r[0] != 0;
        v = (double)iv;
        goto done;
    case PYMB_MAP_STRING: {
        unsigned per = (e->flags & (PYMB_MAP_HIGH_BYTE | PYMB_MAP_LOW_BYTE)) ? e->count
                                                                             : 2u * e->count;
        text(r, e, out->text + e->aux + (size_t)per * channel, &iv, &state);
        if (iv == 0 && nmk > 0) { /* a string's marker 0: the empty text */
            state = marker_state(mk, nmk, 0);
        }
        goto done;
    }
    case PYMB_MAP_RAW:
        iv = (int64_t)reg_index;
        goto done;
    default:
        break;
    }
    u = pattern(r, e);
    switch (e->type) {
    case PYMB_MAP_BIT:
        iv = (int64_t)((u >> e->bit) & 1u);
        v = (double)iv;
        goto done;
    case PYMB_MAP_BITS:
        raw = (u >> e->bit) & (e->width >= 64 ? ~(uint64_t)0 : (((uint64_t)1 << e->width) - 1));
        bits = e->width;
        break;
    case PYMB_MAP_U8_HI:
    case PYMB_MAP_I8_HI:
        raw = u >> 8;
        bits = 8;
        break;
    case PYMB_MAP_U8_LO:
    case PYMB_MAP_I8_LO:
        raw = u & 0xFFu;
        bits = 8;
        break;
    default:
        raw = u;
        break;
    }
    if (e->flags & PYMB_MAP_MASKED) { /* checked: the first marker is the mask */
        raw &= mk[0].raw;
        mk++;
        nmk--;
    }
    state = marker_state(mk, nmk, raw);
    if (state != PYMB_VALUE) {
        goto done;
    }
    if ((e->flags & PYMB_MAP_SCALE_FROM) && !scale_factor(e, regs, &sf)) {
        state = PYMB_MAP_NO_SCALE;
        goto done;
    }
    switch (e->type) {
    case PYMB_MAP_F16:
    case PYMB_MAP_F32:
    case PYMB_MAP_F64:
        if (e->type == PYMB_MAP_F16) {
            v = half_to_double((uint16_t)raw);
        } else if (e->type == PYMB_MAP_F32) {
            uint32_t w = (uint32_t)raw;
            float f;
            memcpy(&f, &w, sizeof f);
            v = (double)f;
        } else {
            memcpy(&v, &raw, sizeof v);
        }
        if (isnan(v)) {
            v = NAN;
            state = PYMB_MAP_NAN;
        } else if (e->flags & (PYMB_MAP_SCALED | PYMB_MAP_OFFSET | PYMB_MAP_SCALE_FROM)) {
            v = apply(e, v, 0, sf);
        }
        goto done;
    case PYMB_MAP_SM16: {
        int negative = (raw & 0x8000u) != 0;
        int64_t mag = (int64_t)(raw & 0x7FFFu);
        iv = negative ? -mag : mag;
        v = (e->flags & (PYMB_MAP_SCALED | PYMB_MAP_OFFSET | PYMB_MAP_SCALE_FROM))
                ? apply(e, (double)mag, negative, sf)
                : (double)iv;
        goto done;
    }
    case PYMB_MAP_I8_HI:
    case PYMB_MAP_I8_LO:
    case PYMB_MAP_I16:
    case PYMB_MAP_I32:
    case PYMB_MAP_I64:
        iv = sign_extend(raw, bits);
        v = (double)iv;
        break;
    default: /* unsigned; a u64 keeps its bit pattern in ints */
        iv = sign_extend(raw, 64);
        v = (double)raw;
        break;
    }
    if (e->flags & (PYMB_MAP_SCALED | PYMB_MAP_OFFSET | PYMB_MAP_SCALE_FROM)) {
        v = apply(e, v, 0, sf);
    }
done:
    out->values[i] = state == PYMB_VALUE ? v : NAN;
    out->states[i] = state;
    if (out->ints != NULL) {
        out->ints[i] = iv;
    }
}

/* A block of 16-bit integer or sign-magnitude values, one a channel, in one
 * loop with no call per channel.
 * The same arithmetic as decode_one() and apply(). What the loop reads of the
 * entry and of out is in locals first: a store into out's arrays (a uint8_t
 * state may alias anything) would otherwise make the compiler read the entry
 * again for every channel. The common cases take decode_16_plain() (below),
 * whose loops decide less per channel; this one takes every other. */
static void decode_16_loop(const pymb_map_entry *e, const pymb_map_marker *mk,
                           const uint16_t *regs, const pymb_map_out *out, const int sm16,
                           const int i16, const int decimals, const int by_scale,
                           const int has_offset)
{
    const unsigned channels = e->channels, nmarkers = e->nmarkers;
    const size_t stride = e->stride;
    const uint16_t *r = regs + e->first;
    double *values = out->values + e->out;
    uint8_t *states = out->states + e->out;
    int64_t *ints = out->ints != NULL ? out->ints + e->out : NULL;
    const int swap = e->order[0] == 1;
    const double divisor = pow10_exact[e->decimals], scale = e->scale, offset = e->offset;
    unsigned c;

    for (c = 0; c < channels; c++) {
        uint16_t raw = r[c * stride];
        uint8_t state = PYMB_VALUE;
        int64_t iv;
        double v;
        int negative = 0;

        if (swap) {
            raw = (uint16_t)(raw << 8 | raw >> 8);
        }
        if (nmarkers) {
            state = marker_state(mk, nmarkers, raw);
        }
        if (state != PYMB_VALUE) {
            values[c] = NAN;
            states[c] = state;
            if (ints != NULL) {
                ints[c] = 0;
            }
            continue;
        }
        if (sm16) {
            int64_t mag = raw & 0x7FFF;
            negative = (raw & 0x8000u) != 0;
            iv = negative ? -mag : mag;
            v = (double)mag; /* the sign after the scale, as apply() does */
        } else {
            iv = i16 ? (int64_t)(int16_t)raw : (int64_t)raw;
            v = (double)iv;
        }
        if (decimals || by_scale || has_offset) {
            if (decimals) {
                v = v / divisor;
            } else if (by_scale) {
                v = v * scale;
            }
            if (negative) {
                v = -v;
            }
            if (has_offset) {
                v = v + offset;
            }
        } else if (negative) {
            v = (double)iv;
        }
        values[c] = v;
        states[c] = PYMB_VALUE;
        if (ints != NULL) {
            ints[c] = iv;
        }
    }
}

/* Whether each marker of an entry is one raw value that means a state (none
 * is a mask, none says PYMB_VALUE). */
static int plain_markers(const pymb_map_marker *mk, unsigned n)
{
    unsigned m;

    for (m = 0; m < n; m++) {
        if (mk[m].state == PYMB_MAP_MARKER_MASK || mk[m].state == PYMB_VALUE) {
            return 0;
        }
    }
    return 1;
}

/* decode_16_loop's common case (the hub's seven blocks): registers in wire
 * order, markers without a mask, no offset, ints wanted. One loop a type with
 * nothing to decide but the value and the first marker; any further marker
 * in a loop of its own. The same arithmetic as decode_16_loop(): a factor of
 * 1 (no scale) multiplies exactly, and a sign-magnitude zero with its sign
 * bit set is -0.0 when scaled, 0.0 when not (-v + zero: -0.0 + 0.0 is 0.0,
 * and adding either zero changes no other value). */
static void decode_16_plain(const pymb_map_entry *e, const pymb_map_marker *mk,
                            const uint16_t *regs, const pymb_map_out *out, const int decimals,
                            const int by_scale)
{
    const unsigned channels = e->channels, nmarkers = e->nmarkers;
    const size_t stride = e->stride;
    const uint16_t *r = regs + e->first;
    double *values = out->values + e->out;
    uint8_t *states = out->states + e->out;
    int64_t *ints = out->ints + e->out;
    const double divisor = pow10_exact[e->decimals], factor = by_scale ? e->scale : 1.0;
    const double zero = decimals || by_scale ? -0.0 : 0.0;
    /* no 16-bit value is 0x10000: a block without markers matches none */
    const uint32_t first = nmarkers > 0 && mk[0].raw <= 0xFFFFu ? (uint32_t)mk[0].raw : 0x10000u;
    const uint8_t first_state = nmarkers > 0 ? mk[0].state : PYMB_VALUE;
    unsigned c, m;
    size_t at;

    /* Each type's loop twice, dividing by 10^decimals or multiplying by the
     * factor: the choice made once, not for every channel (gcc -O2 does not
     * unswitch loops). */
#define PLAIN_SM16(SCALE)                                                                          \
    for (c = 0, at = 0; c < channels; c++, at += stride) {                                         \
        const uint16_t raw = r[at];                                                                \
        const int64_t mag = raw & 0x7FFF;                                                          \
        double v = SCALE((double)mag);                                                             \
        if (raw == first) {                                                                        \
            values[c] = NAN;                                                                       \
            states[c] = first_state;                                                               \
            ints[c] = 0;                                                                           \
            continue;                                                                              \
        }                                                                                          \
        if (raw & 0x8000u) {                                                                       \
            v = -v + zero;                                                                         \
        }                                                                                          \
        values[c] = v;                                                                             \
        states[c] = PYMB_VALUE;                                                                    \
        ints[c] = raw & 0x8000u ? -mag : mag;                                                      \
    }
#define PLAIN_INT(INT_OF, SCALE)                                                                   \
    for (c = 0, at = 0; c < channels; c++, at += stride) {                                         \
        const uint16_t raw = r[at];                                                                \
        const int64_t iv = INT_OF(raw);                                                            \
        if (raw == first) {                                                                        \
            values[c] = NAN;                                                                       \
            states[c] = first_state;                                                               \
            ints[c] = 0;                                                                           \
            continue;                                                                              \
        }                                                                                          \
        values[c] = SCALE((double)iv);                                                             \
        states[c] = PYMB_VALUE;                                                                    \
        ints[c] = iv;                                                                              \
    }
#define BY_DIVISOR(x) ((x) / divisor)
#define BY_FACTOR(x) ((x) * factor)
#define AS_I16(raw) ((int64_t)(int16_t)(raw))
#define AS_U16(raw) ((int64_t)(raw))
    switch (e->type) {
    case PYMB_MAP_SM16:
        if (decimals) {
            PLAIN_SM16(BY_DIVISOR)
        } else {
            PLAIN_SM16(BY_FACTOR)
        }
        break;
    case PYMB_MAP_I16:
        if (decimals) {
            PLAIN_INT(AS_I16, BY_DIVISOR)
        } else {
            PLAIN_INT(AS_I16, BY_FACTOR)
        }
        break;
    default: /* u16 */
        if (decimals) {
            PLAIN_INT(AS_U16, BY_DIVISOR)
        } else {
            PLAIN_INT(AS_U16, BY_FACTOR)
        }
        break;
    }
#undef PLAIN_SM16
#undef PLAIN_INT
#undef BY_DIVISOR
#undef BY_FACTOR
#undef AS_I16
#undef AS_U16
    for (m = 1; m < nmarkers; m++) {
        const uint64_t raw = mk[m].raw;
        const uint8_t state = mk[m].state;

        if (raw > 0xFFFFu || raw == first) {
            continue; /* no 16-bit value is this marker, or an earlier one matched it */
        }
        for (c = 0, at = 0; c < channels; c++, at += stride) {
            if (r[at] == raw && states[c] == PYMB_VALUE) { /* an earlier match stays */
                values[c] = NAN;
                states[c] = state;
                ints[c] = 0;
            }
        }
    }
}

static void decode_16(const pymb_map_entry *e, const pymb_map_marker *mk, const uint16_t *regs,
                      const pymb_map_out *out)
{
    const int sm16 = e->type == PYMB_MAP_SM16, i16 = e->type == PYMB_MAP_I16;
    /* as decode_one(): no scaling without a flag; with one, apply()'s order */
    const int scaled = (e->flags & (PYMB_MAP_SCALED | PYMB_MAP_OFFSET)) != 0;
    const int has_offset = (e->flags & PYMB_MAP_OFFSET) != 0;
    const int decimals = scaled && e->decimals != 0;
    const int by_scale = scaled && !decimals && (e->flags & PYMB_MAP_SCALED) != 0;

    if (!has_offset && e->order[0] != 1 && out->ints != NULL &&
        plain_markers(mk, e->nmarkers)) {
        decode_16_plain(e, mk, regs, out, decimals, by_scale);
        return;
    }
    decode_16_loop(e, mk, regs, out, sm16, i16, decimals, by_scale, has_offset);
}

/* Every entry checked: the slots a decode writes, or -1 (EINVAL). */
static int check_table(const pymb_map_entry *entries, size_t nentries,
                       const pymb_map_marker *markers, size_t nmarkers,
                       const uint16_t *regs, size_t nregs, const pymb_map_out *out)
{
    size_t n, written = 0;

    if ((entries == NULL && nentries > 0) || (markers == NULL && nmarkers > 0) ||
        (regs == NULL && nregs > 0) || out == NULL ||
        (out->len > 0 && (out->values == NULL || out->states == NULL))) {
        errno = EINVAL;
        return -1;
    }
    for (n = 0; n < nentries; n++) {
        /* the count of slots written must fit the int returned */
        if (!entry_ok(&entries[n], nmarkers, nregs, out) ||
            entries[n].channels > (size_t)INT32_MAX - written) {
            errno = EINVAL;
            return -1;
        }
        written += entries[n].channels;
    }
    return (int)written;
}

/* decode_16_plain()'s arithmetic for a point of one channel, an unsigned or
 * signed 16-bit integer in wire order with no marker and no flag but
 * PYMB_MAP_SCALED (the CoolPro's readings): without a block's setup. */
static void decode_single_16(const pymb_map_entry *e, const uint16_t *regs,
                             const pymb_map_out *out)
{
    const uint16_t raw = regs[e->first];
    const int64_t iv = e->type == PYMB_MAP_I16 ? (int64_t)(int16_t)raw : (int64_t)raw;
    double v = (double)iv;

    if (e->flags & PYMB_MAP_SCALED) {
        v = e->decimals ? v / pow10_exact[e->decimals] : v * e->scale;
    }
    out->values[e->out] = v;
    out->states[e->out] = PYMB_VALUE;
    out->ints[e->out] = iv;
}

/* A checked table over regs, into out. */
static void decode_table(const pymb_map_entry *entries, size_t nentries,
                         const pymb_map_marker *markers, const uint16_t *regs,
                         const pymb_map_out *out)
{
    size_t n;
    unsigned c;

    for (n = 0; n < nentries; n++) {
        const pymb_map_entry *e = &entries[n];
        const pymb_map_marker *mk = markers ? markers + e->first_marker : NULL;
        if ((e->type == PYMB_MAP_U16 || e->type == PYMB_MAP_I16 || e->type == PYMB_MAP_SM16) &&
            !(e->flags & (PYMB_MAP_SCALE_FROM | PYMB_MAP_MASKED))) {
            if (e->channels == 1 && e->nmarkers == 0 && e->type != PYMB_MAP_SM16 &&
                (e->flags & ~PYMB_MAP_SCALED) == 0 && e->order[0] != 1 && out->ints != NULL) {
                decode_single_16(e, regs, out);
            } else {
                decode_16(e, mk, regs, out);
            }
            continue;
        }
        for (c = 0; c < e->channels; c++) {
            size_t at = e->first + (size_t)c * e->stride;
            decode_one(e, mk, regs, at, (size_t)e->out + c, c, out);
        }
    }
}

int pymb_map_decode(const pymb_map_entry *entries, size_t nentries,
                    const pymb_map_marker *markers, size_t nmarkers,
                    const uint16_t *regs, size_t nregs, pymb_map_out *out)
{
    int written = check_table(entries, nentries, markers, nmarkers, regs, nregs, out);

    if (written >= 0) {
        decode_table(entries, nentries, markers, regs, out);
    }
    return written;
}

int pymbi_map_ready(pymbi_map_job *job)
{
    int written;

    if (job == NULL) {
        errno = EINVAL;
        return -1;
    }
    job->ready = 0;
    written = check_table(job->entries, job->nentries, job->markers, job->nmarkers, job->regs,
                          job->nregs, &job->out);
    if (written < 0) {
        return -1;
    }
    job->written = written;
    job->ready = 1;
    decode_table(job->entries, job->nentries, job->markers, job->regs, &job->out);
    return written;
}

int pymbi_map_run(const pymbi_map_job *job)
{
    if (job == NULL || job->ready != 1) {
        errno = EINVAL;
        return -1;
    }
    decode_table(job->entries, job->nentries, job->markers, job->regs, &job->out);
    return job->written;
}
