"""A Modbus TCP device some distance away, for ``pymb bench --sections
serve``: ``python -m pymb.bench.farpeer DELAY`` listens on a free port of
127.0.0.1, prints it, and answers each read of registers (03 or 04) DELAY
seconds after it arrived, whatever else is waiting, as a link with that
latency to a fast device (or a gateway with several) would; register N holds
N. Runs until killed."""

from __future__ import annotations

import asyncio
import struct
import sys

from pymb._native.serve import BadFrame, mbap_frame, take_frames

__all__ = ["main"]


class _DelayedDevice(asyncio.Protocol):
    def __init__(self, delay: float) -> None:
        self.delay = delay
        self.buf = bytearray()
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.buf += data
        loop = asyncio.get_running_loop()
        try:  # the C core's MBAP length rule
            frames = take_frames(self.buf)
        except BadFrame:  # a header it refuses: the connection is closed (no traceback)
            if self.transport is not None:
                self.transport.close()
            return
        for frame in frames:
            loop.call_later(self.delay, self._answer, frame)

    def _answer(self, frame: bytes) -> None:
        pdu = frame[7:]
        if len(pdu) == 5 and pdu[0] in (3, 4):
            _fc, address, count = struct.unpack(">BHH", pdu)
            regs = [(address + i) & 0xFFFF for i in range(min(count, 125))]
            reply = struct.pack(f">BB{len(regs)}H", pdu[0], 2 * len(regs), *regs)
        else:
            reply = bytes((pdu[0] | 0x80, 1))
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(mbap_frame(frame[0] << 8 | frame[1], frame[6], reply))


async def _serve(delay: float) -> None:
    loop = asyncio.get_running_loop()
    server = await loop.create_server(lambda: _DelayedDevice(delay), "127.0.0.1", 0)
    print(server.sockets[0].getsockname()[1], flush=True)
    await server.serve_forever()


def main(argv: list[str] | None = None) -> int:
    """Serve until killed."""
    args = sys.argv[1:] if argv is None else argv
    asyncio.run(_serve(float(args[0])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
