"""The controller's half of RoboClaw packet serial, sans-IO: frame the host's bytes, encode replies.

Used by the emulator. It follows the manual's rules for the device: a packet whose bytes are more
than 10 ms apart is discarded ("Packet Timeout"), a write packet with a bad CRC is dropped without
an acknowledgement, and bytes that cannot start a packet are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass

from gprbot.drivers.motors.protocol import FIRST_ADDRESS, LAST_ADDRESS, REQUEST_DATA_SIZE, crc16

PACKET_TIMEOUT_S = 0.010  # manual: "a delay longer than 10ms between bytes" discards the packet


@dataclass(frozen=True)
class Packet:
    """One well-formed host packet (CRC already checked for writes)."""

    address: int
    command: int
    data: bytes

    @property
    def is_read(self) -> bool:
        """True for a read command (the reply carries data and a CRC)."""
        return REQUEST_DATA_SIZE[self.command] is None


def encode_read_reply(address: int, command: int, data: bytes) -> bytes:
    """A read reply: data followed by the CRC over address, command and data."""
    return data + crc16(data, crc16(bytes((address, command)))).to_bytes(2, "big")


class RequestFramer:
    """Splits the host's byte stream into packets the way a controller does.

    `discarded` counts bytes thrown away (noise, unknown commands, bad CRCs, timed-out fragments).
    """

    def __init__(self, packet_timeout_s: float = PACKET_TIMEOUT_S) -> None:
        self.packet_timeout_s = packet_timeout_s
        self.discarded = 0
        self._buffer = bytearray()
        self._last_byte_t: float | None = None

    def feed(self, data: bytes, now: float) -> list[Packet]:
        """Add bytes received at host time `now`; return the packets they complete."""
        if self._buffer and self._last_byte_t is not None and now - self._last_byte_t > self.packet_timeout_s:
            self._drop(len(self._buffer))
        if data:
            self._last_byte_t = now
        self._buffer += data
        packets: list[Packet] = []
        while self._buffer:
            packet, used = self._next_packet()
            if used == 0:
                break  # wait for more bytes
            if packet is None:
                self._drop(used)
            else:
                packets.append(packet)
                del self._buffer[:used]
        return packets

    def _next_packet(self) -> tuple[Packet | None, int]:
        """(packet, bytes used) for the packet at the buffer head; (None, n) to drop n; (None, 0) to wait."""
        buf = self._buffer
        if not FIRST_ADDRESS <= buf[0] <= LAST_ADDRESS:
            return None, 1
        if len(buf) < 2:
            return None, 0
        if buf[1] not in REQUEST_DATA_SIZE:
            return None, 1  # unknown command: resynchronise on the next byte
        size = REQUEST_DATA_SIZE[buf[1]]
        if size is None:
            return Packet(buf[0], buf[1], b""), 2
        total = 2 + size + 2
        if len(buf) < total:
            return None, 0
        if crc16(buf[: 2 + size]) != int.from_bytes(buf[2 + size : total], "big"):
            return None, total
        return Packet(buf[0], buf[1], bytes(buf[2 : 2 + size])), total

    def _drop(self, count: int) -> None:
        del self._buffer[:count]
        self.discarded += count
