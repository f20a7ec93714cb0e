/* SPDX-License-Identifier: MIT */
/*
 * pymb_error.c - pymb_strerror() and pymb_version(): the library's one error
 * vocabulary (the OS's errno values and libmodbus's EMB* codes, which the
 * core defines as PYMB_EMB* so that it needs no libmodbus) and its version.
 */
#include <string.h>

#include "pymb.h"

const char *pymb_version(void)
{
    return PYMB_VERSION_STRING;
}

const char *pymb_strerror(int errnum)
{
    /* [MB-AP] 7: the exception codes' names. */
    switch (errnum) {
    case PYMB_EMBXILFUN:
        return "Illegal function";
    case PYMB_EMBXILADD:
        return "Illegal data address";
    case PYMB_EMBXILVAL:
        return "Illegal data value";
    case PYMB_EMBXSFAIL:
        return "Server device failure";
    case PYMB_EMBXACK:
        return "Acknowledge";
    case PYMB_EMBXSBUSY:
        return "Server device busy";
    case PYMB_EMBXNACK:
        return "Negative acknowledge";
    case PYMB_EMBXMEMPAR:
        return "Memory parity error";
    case PYMB_EMBXGPATH:
        return "Gateway path unavailable";
    case PYMB_EMBXGTAR:
        return "Gateway target device failed to respond";
    case PYMB_EMBBADCRC:
        return "Invalid CRC";
    case PYMB_EMBBADDATA:
        return "Invalid data";
    case PYMB_EMBBADEXC:
        return "Invalid exception code";
    case PYMB_EMBUNKEXC:
        return "Unknown exception code";
    case PYMB_EMBMDATA:
        return "Too many data";
    case PYMB_EMBBADSLAVE:
        return "Response not from requested slave";
    default:
        /* 09 (libmodbus names no EMBX for it) and 0C..FF */
        if (errnum == PYMB_ENOBASE + 9 ||
            (errnum >= PYMB_EXCEPTION_ENOBASE + 0x0C && errnum <= PYMB_EXCEPTION_ENOBASE + 0xFF))
            return "Exception code not defined by the Modbus specification";
        return strerror(errnum);
    }
}
