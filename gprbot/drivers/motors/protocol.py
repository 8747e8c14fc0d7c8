"""RoboClaw packet serial, sans-IO: the CRC, the command table and host commands to bytes.

Source: BasicMicro "RoboClaw Series User Manual", chapters *Packet Serial* and *Advanced Packet
Serial*. A host packet is `[address, command, data..., CRC16 hi, CRC16 lo]`; read commands send only
`[address, command]`. The CRC is CRC16-CCITT (poly 0x1021, init 0, no reflection, i.e. XMODEM) over
every byte before it. Write commands are acknowledged by the single byte 0xFF (nothing if the packet
was invalid); read replies are `data..., CRC16` with the CRC taken over the *sent* address and command
followed by the returned data (decoded in `replies`). All multi-byte values are big-endian.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

ACK = 0xFF
FIRST_ADDRESS, LAST_ADDRESS = 0x80, 0x87  # packet-serial modes 7..14
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC16-CCITT (poly 0x1021, init 0) as the RoboClaw computes it; `crc` continues a running value."""
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    return crc


class Cmd(IntEnum):
    """The packet-serial commands gprbot uses (numbers from the manual)."""

    SET_SERIAL_TIMEOUT = 14
    READ_SERIAL_TIMEOUT = 15
    READ_ENCODER_M1 = 16
    READ_ENCODER_M2 = 17
    READ_SPEED_M1 = 18
    READ_SPEED_M2 = 19
    RESET_ENCODERS = 20
    READ_FIRMWARE_VERSION = 21
    READ_MAIN_BATTERY = 24
    DRIVE_M1_SPEED = 35
    DRIVE_M2_SPEED = 36
    DRIVE_M1_M2_SPEED = 37
    DRIVE_M1_SPEED_ACCEL = 38
    DRIVE_M2_SPEED_ACCEL = 39
    DRIVE_M1_M2_SPEED_ACCEL = 40


# Data bytes the host sends after the command byte; None marks a read (no data, no CRC).
REQUEST_DATA_SIZE: dict[int, int | None] = {
    Cmd.SET_SERIAL_TIMEOUT: 1,
    Cmd.READ_SERIAL_TIMEOUT: None,
    Cmd.READ_ENCODER_M1: None,
    Cmd.READ_ENCODER_M2: None,
    Cmd.READ_SPEED_M1: None,
    Cmd.READ_SPEED_M2: None,
    Cmd.RESET_ENCODERS: 0,
    Cmd.READ_FIRMWARE_VERSION: None,
    Cmd.READ_MAIN_BATTERY: None,
    Cmd.DRIVE_M1_SPEED: 4,
    Cmd.DRIVE_M2_SPEED: 4,
    Cmd.DRIVE_M1_M2_SPEED: 8,
    Cmd.DRIVE_M1_SPEED_ACCEL: 8,
    Cmd.DRIVE_M2_SPEED_ACCEL: 8,
    Cmd.DRIVE_M1_M2_SPEED_ACCEL: 12,
}


@dataclass(frozen=True)
class Request:
    """One host → controller packet; `encode()` gives its bytes, `ReplyParser` reads its answer."""

    address: int
    command: Cmd
    data: bytes = b""

    @property
    def is_read(self) -> bool:
        """True for read commands (no CRC sent, data + CRC returned); False for acknowledged writes."""
        return REQUEST_DATA_SIZE[self.command] is None

    def encode(self) -> bytes:
        """The bytes to send."""
        head = bytes((self.address, self.command)) + self.data
        if self.is_read:
            return head
        return head + crc16(head).to_bytes(2, "big")

    def describe(self) -> str:
        """A short human-readable name, e.g. 'DRIVE_M1_SPEED to 0x80'."""
        return f"{self.command.name} to address {self.address} (0x{self.address:02X})"


def _check_address(address: int) -> None:
    if not FIRST_ADDRESS <= address <= LAST_ADDRESS:
        raise ValueError(f"RoboClaw address must be 128..135 (0x80..0x87), got {address}")


def _int32(value: int, what: str) -> bytes:
    if not INT32_MIN <= value <= INT32_MAX:
        raise ValueError(f"{what} {value} does not fit a signed 32-bit field")
    return struct.pack(">i", value)


def _uint32(value: int, what: str) -> bytes:
    if not 0 <= value < 2**32:
        raise ValueError(f"{what} {value} does not fit an unsigned 32-bit field")
    return struct.pack(">I", value)


def _channel_cmd(channel: int, m1: Cmd, m2: Cmd) -> Cmd:
    if channel not in (1, 2):
        raise ValueError(f"RoboClaw channel must be 1 or 2, got {channel}")
    return m1 if channel == 1 else m2


def _request(address: int, command: Cmd, data: bytes = b"") -> Request:
    _check_address(address)
    return Request(address, command, data)


def drive_speed(address: int, channel: int, counts_per_s: int) -> Request:
    """Commands 35/36: drive one motor at a signed speed (counts/s), accelerating as fast as possible."""
    cmd = _channel_cmd(channel, Cmd.DRIVE_M1_SPEED, Cmd.DRIVE_M2_SPEED)
    return _request(address, cmd, _int32(counts_per_s, "speed"))


def drive_speeds(address: int, m1_counts_per_s: int, m2_counts_per_s: int) -> Request:
    """Command 37: drive both motors at signed speeds (counts/s)."""
    data = _int32(m1_counts_per_s, "M1 speed") + _int32(m2_counts_per_s, "M2 speed")
    return _request(address, Cmd.DRIVE_M1_M2_SPEED, data)


def drive_speed_accel(address: int, channel: int, counts_per_s: int, accel: int) -> Request:
    """Commands 38/39: [Accel (unsigned, counts/s²), Speed (signed, counts/s)] for one motor."""
    cmd = _channel_cmd(channel, Cmd.DRIVE_M1_SPEED_ACCEL, Cmd.DRIVE_M2_SPEED_ACCEL)
    return _request(address, cmd, _uint32(accel, "acceleration") + _int32(counts_per_s, "speed"))


def drive_speeds_accel(address: int, accel: int, m1_counts_per_s: int, m2_counts_per_s: int) -> Request:
    """Command 40: [Accel, SpeedM1, SpeedM2], one unsigned acceleration shared by both motors."""
    data = _uint32(accel, "acceleration") + _int32(m1_counts_per_s, "M1 speed")
    return _request(address, Cmd.DRIVE_M1_M2_SPEED_ACCEL, data + _int32(m2_counts_per_s, "M2 speed"))


def read_encoder(address: int, channel: int) -> Request:
    """Commands 16/17: read a quadrature encoder count and its status byte."""
    return _request(address, _channel_cmd(channel, Cmd.READ_ENCODER_M1, Cmd.READ_ENCODER_M2))


def read_speed(address: int, channel: int) -> Request:
    """Commands 18/19: read a motor's measured speed (counts/s) and direction status."""
    return _request(address, _channel_cmd(channel, Cmd.READ_SPEED_M1, Cmd.READ_SPEED_M2))


def reset_encoders(address: int) -> Request:
    """Command 20: zero both quadrature counters."""
    return _request(address, Cmd.RESET_ENCODERS)


def read_firmware_version(address: int) -> Request:
    """Command 21: read the product name and firmware version."""
    return _request(address, Cmd.READ_FIRMWARE_VERSION)


def read_main_battery(address: int) -> Request:
    """Command 24: read the main battery voltage."""
    return _request(address, Cmd.READ_MAIN_BATTERY)


def serial_timeout_value(timeout_s: float) -> int:
    """The command-14 byte for a timeout in seconds: 100 ms units, 0 (off) to 255 (25.5 s)."""
    value = round(timeout_s * 10)
    if not 0 <= value <= 255:
        raise ValueError(f"serial timeout must be 0 .. 25.5 s (100 ms steps), got {timeout_s} s")
    return value


def set_serial_timeout(address: int, timeout_s: float) -> Request:
    """Command 14: stop both motors when no serial byte arrives for `timeout_s` (0 disables)."""
    return _request(address, Cmd.SET_SERIAL_TIMEOUT, bytes((serial_timeout_value(timeout_s),)))


def read_serial_timeout(address: int) -> Request:
    """Command 15: read the serial-timeout setting back."""
    return _request(address, Cmd.READ_SERIAL_TIMEOUT)
