/* SPDX-License-Identifier: MIT */
/*
 * pymb_map.h - the table-driven decoder of device maps (pymb.map/1).
 *
 * A device map compiles into a small table: one pymb_map_entry per point (a
 * block of channels is one entry), each naming where its registers are in a
 * request's buffer, its type, its byte order, scale, offset and markers.
 * pymb_map_decode() walks the table over the registers of one request and
 * writes every value into caller-owned arrays: no allocation, no I/O, no
 * state between calls. Included by pymb.h; needs only the C99 library.
 *
 * Documents cited:
 *   [MAP]    the pymb.map/1 contract (docs/maps.md): section 3, types and order
 *   [IEEE]   IEEE 754-2008 binary16/32/64
 */
#ifndef PYMB_MAP_H
#define PYMB_MAP_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Types ([MAP] 3). The width of each is fixed (1, 2 or 4 registers) except
 * for PYMB_MAP_STRING and PYMB_MAP_RAW, whose `count` says it, and for
 * PYMB_MAP_BIT/PYMB_MAP_BITS, views of 1, 2 or 4 registers. */
typedef enum {
    PYMB_MAP_BOOL = 0, /* a coil or discrete input: one buffer element per bit */
    PYMB_MAP_BIT,      /* bit `bit` of the value */
    PYMB_MAP_BITS,     /* (value >> bit) & (2^width - 1) */
    PYMB_MAP_U8_HI,    /* the register's first byte after the order is applied */
    PYMB_MAP_U8_LO,
    PYMB_MAP_I8_HI,
    PYMB_MAP_I8_LO,
    PYMB_MAP_U16,
    PYMB_MAP_I16,
    PYMB_MAP_U32,
    PYMB_MAP_I32,
    PYMB_MAP_U64,
    PYMB_MAP_I64,
    PYMB_MAP_F16,
    PYMB_MAP_F32,
    PYMB_MAP_F64,
    PYMB_MAP_SM16,     /* bit 15 sign, bits 14..0 magnitude */
    PYMB_MAP_STRING,
    PYMB_MAP_RAW,
    PYMB_MAP_TYPES     /* how many there are */
} pymb_map_type;

/* Entry flags. */
#define PYMB_MAP_SCALED 0x01u      /* the value is raw * scale (or raw / 10^decimals) */
#define PYMB_MAP_OFFSET 0x02u      /* ... + offset */
#define PYMB_MAP_SWAP 0x04u        /* strings: the two bytes of each register swapped */
#define PYMB_MAP_HIGH_BYTE 0x08u   /* strings: one character a register, its high byte */
#define PYMB_MAP_LOW_BYTE 0x10u    /* strings: one character a register, its low byte */
#define PYMB_MAP_ASCII 0x20u       /* strings: a byte above 0x7F is invalid text */
/* Numbers: the value is raw * 10^SF, SF the int16 at buffer index aux (bit 31
 * of aux cleared) of the same regs; with bit 31 (PYMB_MAP_SF_SWAPPED) set,
 * that register's two bytes are swapped first. An SF of -32768 (SunSpec's
 * "not implemented") or outside PYMB_MAP_SF_MIN..PYMB_MAP_SF_MAX gives no
 * value: the state PYMB_MAP_NO_SCALE. Replaces PYMB_MAP_SCALED. */
#define PYMB_MAP_SCALE_FROM 0x40u
/* Integers: the entry's first marker is no marker but a mask; the value is
 * the bits of the raw value under it (raw & mask), and the markers after
 * it are matched against that. */
#define PYMB_MAP_MASKED 0x80u
#define PYMB_MAP_SF_SWAPPED 0x80000000u
#define PYMB_MAP_SF_MIN (-10)
#define PYMB_MAP_SF_MAX 10

/* States written beside each value; 0..4 are pymb_state's (pymb.h). A map's
 * own marker names take codes from PYMB_MAP_FIRST_MARKER_STATE up. */
#define PYMB_MAP_NAN 5           /* a float's NaN */
#define PYMB_MAP_INVALID_TEXT 6  /* text with a byte its encoding does not allow */
#define PYMB_MAP_NO_SCALE 7      /* PYMB_MAP_SCALE_FROM: the scale factor is not implemented */
/* Not a state: in the markers array, a marker with this state is the care
 * mask of the marker after it, which then matches when (raw & mask) == its
 * raw (a pattern with don't-care bits). */
#define PYMB_MAP_MARKER_MASK 15
#define PYMB_MAP_FIRST_MARKER_STATE 16

/* The longest value: 4 registers, 8 bytes. */
#define PYMB_MAP_MAX_BYTES 8

/* One point, or one block of `channels` values `stride` registers apart. */
typedef struct {
    uint32_t first;    /* buffer index of channel 1's first register */
    uint32_t out;      /* output index of channel 1; channel c is at out + c - 1 */
    uint32_t aux;      /* strings: byte offset of channel 1's text in out->text;
                        * PYMB_MAP_SCALE_FROM: where the scale factor is */
    uint16_t channels; /* 1 for a point */
    uint16_t stride;   /* registers from one channel to the next */
    uint16_t count;    /* registers of one value (the type's width; strings, raw: any) */
    uint16_t first_marker; /* this entry's markers: markers[first_marker ..] */
    uint16_t nmarkers;
    uint8_t type;      /* pymb_map_type */
    uint8_t flags;     /* PYMB_MAP_SCALED, ... */
    uint8_t bit;       /* PYMB_MAP_BIT: the bit; PYMB_MAP_BITS: the shift */
    uint8_t width;     /* PYMB_MAP_BITS: bits in the field */
    uint8_t decimals;  /* 1..22: divide by 10^decimals instead of multiplying by scale */
    /* For each byte of the value, most significant first, its position in the
     * bytes as they arrive (big-endian registers, first register first):
     * ABCD = {0,1,2,3}, CDAB = {2,3,0,1}. See pymb_map_order(). */
    uint8_t order[PYMB_MAP_MAX_BYTES];
    double scale;
    double offset;
} pymb_map_entry;

/* A raw value (the unsigned bit pattern after the order, the bit field or
 * the byte is taken) that means "no value", and the state it gives. */
typedef struct {
    uint64_t raw;
    uint8_t state;
} pymb_map_marker;

/* Where the values go, one slot per channel. values: the engineering value
 * (NaN where the state is not PYMB_VALUE); ints: the exact integer of an
 * integer type (a u64 as its bit pattern), 0 or 1 for bool and bit, the raw
 * integer of a scaled integer; for a string the length of its text up to
 * the first NUL, for raw the buffer index of its first register. states:
 * PYMB_VALUE, a marker's state, PYMB_MAP_NAN or PYMB_MAP_INVALID_TEXT.
 * text: strings' bytes, as laid out (swapped, one per register) but not
 * decoded. ints and text may be NULL when no entry needs them. */
typedef struct {
    double *values;
    int64_t *ints;
    uint8_t *states;
    size_t len;        /* slots in values, ints and states */
    uint8_t *text;
    size_t text_len;
} pymb_map_out;

/* Fill perm[0 .. nbytes) for a byte order given as letters: "ABCD", "CDAB",
 * "BADC", "DCBA" (for any width: 16-bit values keep only the swap, 64-bit
 * ones generalise, CDAB = GHEFCDAB) or an explicit permutation of nbytes
 * letters from A ("BADCFEHG"). nbytes is 2, 4 or 8. Returns 0, or -1 (EINVAL)
 * for anything else. */
int pymb_map_order(const char *letters, int nbytes, uint8_t *perm);

/* Decode every entry of a table over one request's registers.
 *
 * regs, nregs: the registers as read (for coil and discrete points, one
 * element per bit, 0 or 1). Every entry must lie inside them; every output
 * slot inside out. Returns the number of slots written, or -1 with errno
 * EINVAL when an argument or an entry is invalid: then nothing is written.
 * Data never fails: a marker, a NaN or invalid text is a state.
 */
int pymb_map_decode(const pymb_map_entry *entries, size_t nentries,
                    const pymb_map_marker *markers, size_t nmarkers,
                    const uint16_t *regs, size_t nregs, pymb_map_out *out);

#ifdef __cplusplus
}
#endif

#endif /* PYMB_MAP_H */
