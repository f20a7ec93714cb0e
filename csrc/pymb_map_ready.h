/* SPDX-License-Identifier: MIT */
/*
 * pymb_map_ready.h - a decode made ready: pymb_map_decode()'s arguments
 * checked once, then decoded again and again with one call and no checks.
 * For a reader that decodes the same buffer into the same arrays on every
 * poll (pymb.maps.Decoder.bind, through the Python extension).
 *
 * Not installed; the names are pymbi_* (the version script exports pymb_*
 * only). Needs only the C99 library and pymb_map.c.
 */
#ifndef PYMB_MAP_READY_H
#define PYMB_MAP_READY_H

#include <stddef.h>
#include <stdint.h>

#include "pymb_map.h"

/* pymb_map_decode()'s arguments, held. pymbi_map_ready() sets `ready` (1
 * when the arguments passed its checks, 0 otherwise: a zeroed job is not
 * ready) and `written`, the slots a decode writes. Between
 * pymbi_map_ready() and the last pymbi_map_run(), nothing it points to may
 * change its size, and the entries and markers may not change at all. */
typedef struct {
    const pymb_map_entry *entries;
    size_t nentries;
    const pymb_map_marker *markers;
    size_t nmarkers;
    const uint16_t *regs;
    size_t nregs;
    pymb_map_out out;
    int ready;
    int written;
} pymbi_map_job;

/* Check the job as pymb_map_decode() checks its arguments, and decode once.
 * Returns the slots written, or -1 with errno EINVAL (the job is then not
 * ready). */
int pymbi_map_ready(pymbi_map_job *job);

/* Decode the job's registers again: the slots written, or -1 with errno
 * EINVAL when the job is NULL or not ready. */
int pymbi_map_run(const pymbi_map_job *job);

#endif /* PYMB_MAP_READY_H */
