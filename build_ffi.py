"""Build pymb's cffi extension, ``pymb._pymb_cffi`` (out-of-line API mode).

The extension is compiled C: the compiler checks every declaration below
against libmodbus's and pymb's headers, and fills in every constant and enum
value written as ``...`` (function codes and limits, the Modbus exception
codes, libmodbus's and the OS's errno values, pymb's frame statuses and value
states), so nothing here is copied by hand. The cdef declares
only what ``pymb._native`` uses, and the exception codes ``pymb.errors``
reads (it sits below ``_native``); ``pymb._native`` turns the constants into
Python enums. libmodbus is found
through pkg-config; pymb's own C core (``csrc/*.c``) is compiled into the same
extension.

Run by setuptools through ``setup.py``; ``python build_ffi.py`` builds in place.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig

from cffi import FFI

HERE = os.path.dirname(os.path.abspath(__file__))
CSRC = "csrc"
SOURCES = [
    f"{CSRC}/pymb_crc.c",
    f"{CSRC}/pymb_frame.c",
    f"{CSRC}/pymb_error.c",
    f"{CSRC}/pymb_line.c",
    f"{CSRC}/pymb_request.c",
    f"{CSRC}/pymb_rtu.c",
    f"{CSRC}/pymb_tcp.c",
    f"{CSRC}/pymb_rtu_tcp.c",
    f"{CSRC}/pymb_ascii.c",
    f"{CSRC}/pymb_udp.c",
    f"{CSRC}/pymb_map.c",
    f"{CSRC}/pymb_master.c",
    f"{CSRC}/pymb_serve.c",  # the extension's alone (not in libpymb)
    f"{CSRC}/pymb_loop.c",  # the extension's alone (not in libpymb)
]

CDEF = """
/* ---- libmodbus (modbus.h, modbus-rtu.h, modbus-tcp.h) ---- */
typedef struct _modbus modbus_t;

#define MODBUS_FC_READ_COILS ...
#define MODBUS_FC_READ_DISCRETE_INPUTS ...
#define MODBUS_FC_READ_HOLDING_REGISTERS ...
#define MODBUS_FC_READ_INPUT_REGISTERS ...
#define MODBUS_FC_WRITE_SINGLE_COIL ...
#define MODBUS_FC_WRITE_SINGLE_REGISTER ...
#define MODBUS_FC_READ_EXCEPTION_STATUS ...
#define MODBUS_FC_WRITE_MULTIPLE_COILS ...
#define MODBUS_FC_WRITE_MULTIPLE_REGISTERS ...
#define MODBUS_FC_REPORT_SLAVE_ID ...
#define MODBUS_FC_MASK_WRITE_REGISTER ...
#define MODBUS_FC_WRITE_AND_READ_REGISTERS ...
#define MODBUS_MAX_READ_BITS ...
#define MODBUS_MAX_WRITE_BITS ...
#define MODBUS_MAX_READ_REGISTERS ...
#define MODBUS_MAX_WRITE_REGISTERS ...
#define MODBUS_MAX_WR_WRITE_REGISTERS ...
#define MODBUS_MAX_WR_READ_REGISTERS ...
#define MODBUS_MAX_ADU_LENGTH ...
#define MODBUS_RTU_RS232 ...
#define MODBUS_RTU_RS485 ...
#define MODBUS_RTU_RTS_NONE ...
#define MODBUS_RTU_RTS_UP ...
#define MODBUS_RTU_RTS_DOWN ...

/* the Modbus exception codes (libmodbus's enum): pymb.errors's DeviceException classes */
#define MODBUS_EXCEPTION_ILLEGAL_FUNCTION ...
#define MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS ...
#define MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE ...
#define MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE ...
#define MODBUS_EXCEPTION_ACKNOWLEDGE ...
#define MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY ...
#define MODBUS_EXCEPTION_NEGATIVE_ACKNOWLEDGE ...
#define MODBUS_EXCEPTION_MEMORY_PARITY ...
#define MODBUS_EXCEPTION_GATEWAY_PATH ...
#define MODBUS_EXCEPTION_GATEWAY_TARGET ...

/* libmodbus's exception errno values: tests/test_packaging.py checks pymb_strerror's text */
#define EMBXILFUN ...
#define EMBXILADD ...
#define EMBXILVAL ...
#define EMBXSFAIL ...
#define EMBXACK ...
#define EMBXSBUSY ...
#define EMBXNACK ...
#define EMBXMEMPAR ...
#define EMBXGPATH ...
#define EMBXGTAR ...
#define EMBBADCRC ...
#define EMBBADDATA ...
#define EMBBADEXC ...
#define EMBUNKEXC ...
#define EMBMDATA ...
#define EMBBADSLAVE ...

extern const unsigned int libmodbus_version_major;
extern const unsigned int libmodbus_version_minor;
extern const unsigned int libmodbus_version_micro;

modbus_t *modbus_new_rtu(const char *device, int baud, char parity, int data_bit,
                         int stop_bit);
modbus_t *modbus_new_tcp_pi(const char *node, const char *service);
int modbus_connect(modbus_t *ctx);
void modbus_close(modbus_t *ctx);
void modbus_free(modbus_t *ctx);
int modbus_get_socket(modbus_t *ctx);
int modbus_set_socket(modbus_t *ctx, int s);
int modbus_set_response_timeout(modbus_t *ctx, uint32_t to_sec, uint32_t to_usec);
int modbus_set_byte_timeout(modbus_t *ctx, uint32_t to_sec, uint32_t to_usec);
int modbus_rtu_set_serial_mode(modbus_t *ctx, int mode);
int modbus_rtu_set_rts(modbus_t *ctx, int mode);
int modbus_rtu_set_rts_delay(modbus_t *ctx, int us);

/* ---- pymb.h ---- */
#define PYMB_MAX_PDU ...
#define PYMB_MAX_READ_REGISTERS ...
#define PYMB_MAX_READ_BITS ...

typedef enum {
    PYMB_FRAME_OK,
    PYMB_FRAME_EXCEPTION,
    PYMB_FRAME_INCOMPLETE,
    PYMB_FRAME_BAD_CRC,
    PYMB_FRAME_BAD_SLAVE,
    PYMB_FRAME_BAD_FUNCTION,
    PYMB_FRAME_BAD_LENGTH,
    PYMB_FRAME_BAD_ECHO,
    PYMB_FRAME_TOO_LONG,
    PYMB_FRAME_INVALID,
    PYMB_FRAME_BAD_HEADER,
    PYMB_FRAME_BAD_TEXT,
    PYMB_FRAME_BAD_TID,
    ...
} pymb_frame_status;

typedef enum {
    PYMB_VALUE,
    PYMB_OFFLINE,
    PYMB_NO_SENSOR,
    PYMB_UNSUPPORTED,
    PYMB_NOT_READ,
    ...
} pymb_state;

uint16_t pymb_crc16(const uint8_t *data, size_t len);
int pymb_rtu_crc_ok(const uint8_t *frame, size_t len);
int pymb_rtu_append_crc(uint8_t *frame, size_t len, size_t cap);
const char *pymb_version(void);
const char *pymb_strerror(int errnum);
const char *pymb_frame_strerror(pymb_frame_status status);
int pymb_rtu_response_length(const uint8_t *rsp, size_t have);
int pymb_rtu_request_length(const uint8_t *req, size_t have);

/* ---- pymb_modbus.h ---- */
typedef enum {
    PYMB_FRAMING_RTU,
    PYMB_FRAMING_TCP,
    PYMB_FRAMING_RTU_OVER_TCP,
    PYMB_FRAMING_ASCII,
    PYMB_FRAMING_UDP,
    ...
} pymb_framing;
#define PYMB_INTERRUPT_SLICE_US ...

typedef struct pymb_line pymb_line;

typedef struct {
    int address;
    int count;
    int frame;
    int rsp_len;
    int header;
    uint8_t rsp[...];
    ...;
} pymb_failure;

int pymb_exception_errno(int code);
int pymb_errno_exception(int errnum);
pymb_line *pymb_line_new(modbus_t *ctx, pymb_framing framing, uint32_t silence_us);
void pymb_line_free(pymb_line *line);
int pymb_line_set_interrupt(pymb_line *line, int (*interrupted)(void *arg), void *arg);
int pymb_line_set_char_ns(pymb_line *line, uint32_t char_ns);
typedef struct {
    int (*read)(void *arg, uint8_t *buf, int n);
    int (*write)(void *arg, const uint8_t *buf, int n);
    int (*pending)(void *arg);
    void *arg;
} pymb_line_io;
int pymb_line_set_io(pymb_line *line, const pymb_line_io *io);
int pymb_line_header_length(const pymb_line *line);
int pymb_line_connect(pymb_line *line, const char *node, const char *service);
void pymb_line_close(pymb_line *line);
int pymb_line_set_retries(pymb_line *line, int retries);
uint32_t pymb_rtu_silence_us(int baud);
uint32_t pymb_rtu_char_ns(int baud, int bits);
int pymb_drain(pymb_line *line, uint32_t quiet_us, uint32_t max_us);
int pymb_transact(pymb_line *line, const uint8_t *req, int req_len, int expect,
                  uint8_t *rsp, int rsp_cap, pymb_failure *fail);
int pymb_read_registers(pymb_line *line, int function, int slave, int addr, int nb,
                        uint16_t *dest, pymb_failure *fail);
int pymb_read_bits(pymb_line *line, int function, int slave, int addr, int nb,
                   uint8_t *dest, pymb_failure *fail);
typedef struct {
    uint8_t function; uint8_t slave; uint16_t address; uint16_t count; uint32_t offset;
} pymb_plan_request;
int pymb_read_plan(pymb_line *line, const pymb_plan_request *reqs, size_t n, uint32_t gap_us,
                   uint16_t *regs, size_t nregs, size_t *done, pymb_failure *fail);

/* The interrupt hook: pymb._native calls Python's pending signal handlers. */
extern "Python" int pymb_py_interrupted(void *arg);
/* Every line's hook (the extension's, below): its Link's stop flag, then `then`. */
typedef int... sig_atomic_t;
typedef struct {
    volatile sig_atomic_t stop; int (*then)(void *arg); unsigned long main_thread; ...;
} pymbi_stop;
int pymbi_stop_hook(void *arg);
/* TLS under a line (pymb._native.tls): the line's I/O, over Python's ssl. */
extern "Python" int pymb_py_tls_read(void *arg, uint8_t *buf, int n);
extern "Python" int pymb_py_tls_write(void *arg, const uint8_t *buf, int n);
extern "Python" int pymb_py_tls_pending(void *arg);

/* ---- a few OS calls the port lock and the link checks need ---- */
#define FD_SETSIZE ...
#define LOCK_EX ...
#define LOCK_NB ...
int flock(int fd, int operation);
"""

SOURCE = """
#include <errno.h>
#include <sys/file.h>
#include <sys/select.h>
#include <modbus.h>
#include "pymb.h"
#include "pymb_modbus.h"
#include "pymb_master.h"
#include "pymb_map_ready.h"
#include "pymb_internal.h"
#include "pymb_serve.h"
#include "pymb_loop.h"
#include <pthread.h>
#include <signal.h>

/* A line's interrupt hook (pymb_line_set_interrupt), arg a pymbi_stop its
 * Link owns: `stop`, set from any thread (Link.stop: a close() while a
 * request waits), ends the wait within PYMB_INTERRUPT_SLICE_US with EINTR;
 * `then` (pymb_py_interrupted: Python's signal handlers) is asked next, but
 * only when the waiting thread is `main_thread` (Python's main thread, whose
 * identifier is its pthread_self()): signal handlers run there alone, and a
 * daemon thread's call could meet the interpreter's shutdown. Whichever
 * thread opened the line. */
typedef struct {
    volatile sig_atomic_t stop;
    int (*then)(void *arg);
    unsigned long main_thread;
} pymbi_stop;

static int pymbi_stop_hook(void *arg)
{
    const pymbi_stop *s = arg;
    if (s->stop != 0) {
        return 1;
    }
    if (s->then == NULL || (unsigned long)pthread_self() != s->main_thread) {
        return 0;
    }
    /* a handler run by `then` may have closed the client (the flag up) */
    return s->then(NULL) != 0 || s->stop != 0;
}
"""


# pymb_map.h: the table-driven map decoder (pymb.maps._decode is its one user).
MAP_CDEF = """
typedef enum {
    PYMB_MAP_BOOL, PYMB_MAP_BIT, PYMB_MAP_BITS, PYMB_MAP_U8_HI, PYMB_MAP_U8_LO,
    PYMB_MAP_I8_HI, PYMB_MAP_I8_LO, PYMB_MAP_U16, PYMB_MAP_I16, PYMB_MAP_U32, PYMB_MAP_I32,
    PYMB_MAP_U64, PYMB_MAP_I64, PYMB_MAP_F16, PYMB_MAP_F32, PYMB_MAP_F64, PYMB_MAP_SM16,
    PYMB_MAP_STRING, PYMB_MAP_RAW, PYMB_MAP_TYPES, ...
} pymb_map_type;
#define PYMB_MAP_SCALED ...
#define PYMB_MAP_OFFSET ...
#define PYMB_MAP_SWAP ...
#define PYMB_MAP_HIGH_BYTE ...
#define PYMB_MAP_LOW_BYTE ...
#define PYMB_MAP_ASCII ...
#define PYMB_MAP_SCALE_FROM ...
#define PYMB_MAP_MASKED ...
#define PYMB_MAP_SF_SWAPPED ...
#define PYMB_MAP_NO_SCALE ...
#define PYMB_MAP_MARKER_MASK ...
#define PYMB_MAP_NAN ...
#define PYMB_MAP_INVALID_TEXT ...
#define PYMB_MAP_FIRST_MARKER_STATE ...
#define PYMB_MAP_MAX_BYTES ...
typedef struct {
    uint32_t first; uint32_t out; uint32_t aux;
    uint16_t channels; uint16_t stride; uint16_t count; uint16_t first_marker; uint16_t nmarkers;
    uint8_t type; uint8_t flags; uint8_t bit; uint8_t width; uint8_t decimals;
    uint8_t order[...];
    double scale; double offset;
    ...;
} pymb_map_entry;
typedef struct { uint64_t raw; uint8_t state; ...; } pymb_map_marker;
typedef struct {
    double *values; int64_t *ints; uint8_t *states; size_t len; uint8_t *text; size_t text_len;
    ...;
} pymb_map_out;
int pymb_map_order(const char *letters, int nbytes, uint8_t *perm);
int pymb_map_decode(const pymb_map_entry *entries, size_t nentries,
                    const pymb_map_marker *markers, size_t nmarkers,
                    const uint16_t *regs, size_t nregs, pymb_map_out *out);
/* pymb_map_ready.h (internal): a decode checked once, run again with one call */
typedef struct {
    const pymb_map_entry *entries; size_t nentries; const pymb_map_marker *markers;
    size_t nmarkers; const uint16_t *regs; size_t nregs; pymb_map_out out; int ready;
    int written;
} pymbi_map_job;
int pymbi_map_ready(pymbi_map_job *job);
int pymbi_map_run(const pymbi_map_job *job);
/* pymb_internal.h: a read plan held, decoded once its requests have their replies */
typedef struct {
    const pymb_plan_request *reqs; size_t n; uint32_t gap_us; uint16_t *regs; size_t nregs;
    const pymbi_map_job *then; size_t done; int decoded; pymb_line *line; pymb_failure *fail;
} pymbi_plan;
int pymbi_plan_run(pymb_line *line, pymbi_plan *plan, size_t start, pymb_failure *fail);
int pymbi_plan_go(pymbi_plan *plan);
/* pymb_internal.h: the transaction id a TCP or UDP line's next request gets */
uint16_t pymbi_line_tid(const pymb_line *line);
void pymbi_line_set_tid(pymb_line *line, uint16_t tid);
"""


# pymb_master.h: the sans-I/O Modbus TCP master (pymb._native.master is its one
# Python user) and the MBAP rules it shares (pymb._native.serve splits and checks
# an upstream's replies with them); internal (pymbi_*), not exported by libpymb.
MASTER_CDEF = """
#define PYMBI_MASTER_FRAME ...
#define PYMBI_MASTER_HEAD ...
#define PYMBI_MASTER_ADU ...
#define PYMBI_MASTER_INFLIGHT ...
#define PYMBI_NO_TOKEN ...
#define PYMBI_MREQ_PACKED ...
#define PYMBI_EV_EXCEPTION ...
#define PYMBI_EV_LATE ...
#define PYMBI_EV_FOREIGN ...
#define PYMBI_EV_BAD ...
typedef struct {
    uint32_t offset; uint32_t token; uint16_t address; uint16_t count; uint8_t unit;
    uint8_t function; uint8_t flags;
} pymbi_mreq;
typedef struct {
    int kind; int status; uint32_t token; uint16_t tid; uint8_t code;
} pymbi_mevent;
typedef struct {
    uint16_t next_tid; uint32_t in_flight; uint64_t replies; int broken; size_t part_len;
    uint8_t part[...]; size_t bad_len; uint8_t bad[...]; uint32_t dropped; size_t drop_len;
    uint8_t drop[...];
    ...;
} pymbi_master;
void pymbi_master_reset(pymbi_master *m, uint16_t tid);
void pymbi_master_forget(pymbi_master *m);
int pymbi_master_frames(pymbi_master *m, const pymbi_mreq *reqs, size_t n, size_t image_len,
                        uint8_t *out, size_t out_cap);
int pymbi_master_take(pymbi_master *m, const uint8_t *buf, size_t len, uint8_t *image,
                      size_t image_len, pymbi_mevent *ev, size_t ev_cap, size_t *used);
int pymbi_master_step(pymbi_master *m, const uint8_t *buf, size_t len, uint8_t *image,
                      size_t image_len, pymbi_mevent *ev, size_t ev_cap, size_t *used,
                      const pymbi_mreq *again, size_t n, uint8_t *out, size_t out_cap,
                      size_t *framed);
size_t pymbi_master_pending(const pymbi_master *m, uint32_t *tokens, size_t cap);
int pymbi_mbap_length(const uint8_t *adu, size_t have);
int pymbi_tcp_check(uint8_t unit, const uint8_t *req_pdu, size_t req_len, const uint8_t *adu,
                    size_t n, int *exception_code);
"""


# pymb_serve.h: the requests pymb serve takes from its clients (pymb.serve is its one
# user); internal to the extension, not part of libpymb.
SERVE_CDEF = """
#define PYMBI_SRV_MBAP ...
#define PYMBI_SRV_MAX_PDU ...
#define PYMBI_SRV_MAX_FRAME ...
typedef struct {
    uint16_t tid; uint8_t unit; uint8_t function; uint16_t pdu_len; uint8_t exception; ...;
} pymbi_srv_req;
int pymbi_srv_check_pdu(const uint8_t *pdu, size_t len);
int pymbi_srv_take(const uint8_t *buf, size_t len, pymbi_srv_req *req);
int pymbi_srv_reply(uint16_t tid, uint8_t unit, const uint8_t *pdu, size_t pdu_len,
                    uint8_t *out, size_t out_cap);
int pymbi_srv_exception(uint16_t tid, uint8_t unit, uint8_t function, uint8_t code,
                        uint8_t *out, size_t out_cap);
"""


# pymb_loop.h: the I/O of pymb log's one TCP loop, flat out and chains (pymb._native.loop is
# its one user); internal to the extension, not part of libpymb.
LOOP_CDEF = """
#define PYMBI_LOOP_READY ...
#define PYMBI_LOOP_DONE ...
#define PYMBI_LOOP_TAKEN ...
#define PYMBI_LOOP_LOOK ...
#define PYMBI_LOOP_END ...
#define PYMBI_LOOP_UNSENT ...
#define PYMBI_LOOP_NO_CONN ...
typedef struct {
    const pymbi_mreq *reqs; size_t n; uint8_t *image; size_t image_len; double timeout;
    uint32_t id;
} pymbi_lpoll;
typedef struct {
    int fd; int armed; pymbi_master *m; const pymbi_mreq *reqs; size_t n; uint8_t *image;
    size_t image_len; pymbi_mevent *ev; size_t ev_cap; size_t replies; double timeout;
    double took; double sent_at; double look_at; double deadline; uint32_t asked;
    uint32_t id; const pymbi_lpoll *chain; size_t nchain; size_t at; size_t sent;
    size_t window; int lowat;
} pymbi_lconn;
typedef struct {
    int kind; int fd; uint32_t conn; uint32_t events; int err; int nev; size_t size;
    size_t sent; size_t got; size_t used; uint64_t taken; double now;
} pymbi_lrec;
typedef struct {
    int epfd; pymbi_lconn *conns; size_t nconns; const int32_t *slot_of; size_t slot_cap;
    uint8_t *rx; size_t rx_cap; uint8_t *out; size_t out_cap; double look_min; uint32_t *done;
    size_t done_cap; size_t ndone; double now; uint8_t *block; size_t block_cap;
    size_t block_len; uint32_t *done_off; double *done_at; double hold; double gap;
} pymbi_loop;
int pymbi_loop_wait(pymbi_loop *lp, double timeout, pymbi_lrec *rec, size_t cap);
"""


def _require_build_tools() -> None:
    """Stop with one line naming the Debian packages when a build need is missing."""
    pkg_config = os.environ.get("PKG_CONFIG", "pkg-config")
    missing = []
    if shutil.which(pkg_config) is None:
        missing.append("pkg-config")
    elif subprocess.run([pkg_config, "--exists", "libmodbus"], check=False).returncode != 0:
        missing.append("libmodbus-dev")
    if not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")):
        missing.append("python3-dev")
    if missing:
        sys.exit(f"pymb: cannot build its C extension: install {' and '.join(missing)} first "
                 f"(Debian/Ubuntu: sudo apt install {' '.join(missing)})")


_require_build_tools()
ffibuilder = FFI()
ffibuilder.cdef(CDEF)
ffibuilder.cdef(MAP_CDEF)
ffibuilder.cdef(MASTER_CDEF)
ffibuilder.cdef(SERVE_CDEF)
ffibuilder.cdef(LOOP_CDEF)
ffibuilder.set_source_pkgconfig(
    "pymb._pymb_cffi",
    ["libmodbus"],
    SOURCE,
    sources=SOURCES,
    include_dirs=[CSRC],
    libraries=["m"],
    extra_compile_args=["-std=c99", "-O2", "-Wall", "-Wextra", "-Wno-unused-parameter"],
)

if __name__ == "__main__":
    os.chdir(HERE)
    ffibuilder.compile(tmpdir=".", verbose=True)
