"""One WebSocket frame built once and written to many connections.

A server's WebSocket frames are not masked (RFC 6455, section 5.1), so the frame of a binary
message is the same bytes for every client: the hub builds it once per published message and
writes it straight to each idle connection's transport, instead of waking each client's send
task to have aiohttp frame the same message again (docs/benchmarks.md: the wake-up, not the
framing, is most of a message's cost). aiohttp has no public call that sends a pre-built frame,
hence these few lines.
"""

from __future__ import annotations

import struct

OPCODE_BINARY = 0x2
FIN = 0x80


def binary_frame(payload: bytes) -> bytes:
    """The whole unmasked, unfragmented frame of one binary message (RFC 6455, 5.2).

    Lengths below 126 go in the first length byte, up to 65535 in a 16-bit extension (126),
    longer in a 64-bit one (127), all big-endian.
    """
    n = len(payload)
    if n < 126:
        header = struct.pack("!BB", FIN | OPCODE_BINARY, n)
    elif n < 1 << 16:
        header = struct.pack("!BBH", FIN | OPCODE_BINARY, 126, n)
    else:
        header = struct.pack("!BBQ", FIN | OPCODE_BINARY, 127, n)
    return header + payload
