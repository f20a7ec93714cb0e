/* SPDX-License-Identifier: MIT */
/* pymb_internal.h - helpers shared by the request-path sources; not installed. */
#ifndef PYMB_INTERNAL_H
#define PYMB_INTERNAL_H

#include "pymb_modbus.h"

/* What every function taking a pymb_failure writes first, even when it then
 * refuses its arguments: nothing asked, nothing received. */
static inline void pymb_failure_reset(pymb_failure *fail)
{
    if (fail != NULL) {
        fail->function = -1;
        fail->address = -1;
        fail->count = -1;
        fail->frame = 0;
        fail->rsp_len = 0;
        fail->header = 0;
    }
}

#endif /* PYMB_INTERNAL_H */
