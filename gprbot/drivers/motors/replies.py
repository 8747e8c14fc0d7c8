"""RoboClaw packet serial, sans-IO: the controller's reply bytes to values (host side).

A write is acknowledged by the single byte 0xFF; a read reply is `data..., CRC16` with the CRC over
the sent address and command followed by the returned data (manual, "CRC16 Checksum Calculation for
Received data"). A value is only returned once its CRC has been checked.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from gprbot.drivers.motors.protocol import ACK, Cmd, Request, crc16
from gprbot.errors import ProtocolError

MAX_VERSION_BYTES = 48  # "Returns up to 48 bytes", terminated by line feed and NUL

# Data bytes in a read command's reply (before its CRC); -1: the NUL-terminated version string.
REPLY_DATA_SIZE: dict[int, int] = {
    Cmd.READ_SERIAL_TIMEOUT: 1,
    Cmd.READ_ENCODER_M1: 5,
    Cmd.READ_ENCODER_M2: 5,
    Cmd.READ_SPEED_M1: 5,
    Cmd.READ_SPEED_M2: 5,
    Cmd.READ_FIRMWARE_VERSION: -1,
    Cmd.READ_MAIN_BATTERY: 2,
}


@dataclass(frozen=True)
class Ack:
    """A write command was accepted (the controller sent 0xFF)."""


@dataclass(frozen=True)
class EncoderCount:
    """Quadrature count (0 .. 2³²-1, wraps) and status: bit0 underflow, bit1 backwards, bit2 overflow."""

    count: int
    status: int

    @property
    def underflow(self) -> bool:
        """The counter wrapped below zero since the last read."""
        return bool(self.status & 0x01)

    @property
    def overflow(self) -> bool:
        """The counter wrapped above 2³²-1 since the last read."""
        return bool(self.status & 0x04)


@dataclass(frozen=True)
class EncoderSpeed:
    """Measured speed in quadrature counts per second (signed), status bit0 = turning backwards."""

    counts_per_s: int
    status: int


@dataclass(frozen=True)
class FirmwareVersion:
    """The product name and firmware version, e.g. 'USB Roboclaw 2x15a v4.1.34'."""

    text: str


@dataclass(frozen=True)
class BatteryVoltage:
    """Main battery voltage in volts (the controller reports tenths of a volt)."""

    volts: float


@dataclass(frozen=True)
class SerialTimeout:
    """The serial-timeout failsafe in seconds (0: disabled)."""

    timeout_s: float


Reply = Ack | EncoderCount | EncoderSpeed | FirmwareVersion | BatteryVoltage | SerialTimeout


def _decode_data(command: Cmd, data: bytes) -> Reply:
    if command in (Cmd.READ_ENCODER_M1, Cmd.READ_ENCODER_M2):
        count, status = struct.unpack(">IB", data)
        return EncoderCount(count, status)
    if command in (Cmd.READ_SPEED_M1, Cmd.READ_SPEED_M2):
        # The manual calls the value "speed" with a direction flag; firmware sends two's complement.
        speed, status = struct.unpack(">iB", data)
        return EncoderSpeed(speed, status)
    if command is Cmd.READ_MAIN_BATTERY:
        return BatteryVoltage(struct.unpack(">H", data)[0] / 10.0)
    if command is Cmd.READ_SERIAL_TIMEOUT:
        return SerialTimeout(data[0] / 10.0)
    text = data[:-1].decode("ascii", errors="replace").rstrip("\n")  # drop NUL, then line feed
    return FirmwareVersion(text)


class ReplyParser:
    """Incrementally decodes the reply to one request; `feed` returns the value once it is complete.

    Raises ProtocolError on a CRC mismatch, an acknowledgement other than 0xFF or an over-long
    version string. Bytes after a complete reply are left in `unused` (the caller discards them).
    """

    def __init__(self, request: Request) -> None:
        self.request = request
        self.unused = b""
        self._buffer = bytearray()
        self._head = bytes((request.address, request.command))
        self._done = False

    def feed(self, data: bytes) -> Reply | None:
        """Add received bytes; the decoded reply when complete, else None."""
        if self._done:
            self.unused += data
            return None
        self._buffer += data
        if not self.request.is_read:
            return self._ack()
        size = REPLY_DATA_SIZE[self.request.command]
        if size < 0:
            size = self._version_size()
            if size < 0:
                return None
        if len(self._buffer) < size + 2:
            return None
        payload = bytes(self._buffer[:size])
        received_crc = int.from_bytes(self._buffer[size : size + 2], "big")
        self._finish(size + 2)
        expected_crc = crc16(payload, crc16(self._head))
        if received_crc != expected_crc:
            raise ProtocolError(
                f"{self.request.describe()}: reply CRC 0x{received_crc:04X} != 0x{expected_crc:04X} "
                "(line noise, wrong baud rate or not a RoboClaw)"
            )
        return _decode_data(self.request.command, payload)

    def _ack(self) -> Reply | None:
        if not self._buffer:
            return None
        first = self._buffer[0]
        self._finish(1)
        if first != ACK:
            raise ProtocolError(f"{self.request.describe()}: expected acknowledgement 0xFF, got 0x{first:02X}")
        return Ack()

    def _version_size(self) -> int:
        end = self._buffer.find(0, 0, MAX_VERSION_BYTES)
        if end >= 0:
            return end + 1
        if len(self._buffer) >= MAX_VERSION_BYTES:
            self._finish(len(self._buffer))
            raise ProtocolError(
                f"{self.request.describe()}: version string not NUL-terminated within {MAX_VERSION_BYTES} bytes"
            )
        return -1

    def _finish(self, used: int) -> None:
        self.unused = bytes(self._buffer[used:])
        self._buffer.clear()
        self._done = True


def decode_reply(request: Request, data: bytes) -> Reply:
    """Decode one complete reply (no more, no fewer bytes); raises ProtocolError otherwise."""
    parser = ReplyParser(request)
    reply = parser.feed(data)
    if reply is None:
        raise ProtocolError(f"{request.describe()}: reply truncated after {len(data)} bytes")
    if parser.unused:
        raise ProtocolError(f"{request.describe()}: {len(parser.unused)} unexpected bytes after the reply")
    return reply
