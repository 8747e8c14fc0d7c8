"""RoboClaw packet serial, sans-IO: exact bytes, hand-worked CRCs, parser robustness, emulator core."""

from __future__ import annotations

import binascii
import contextlib
import math
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gprbot.drivers.motors import protocol as rc
from gprbot.drivers.motors import replies
from gprbot.drivers.motors.device_side import Packet, RequestFramer, encode_read_reply
from gprbot.drivers.motors.emulator import RoboClawEmulator
from gprbot.drivers.motors.motor_model import LaggedMotor
from gprbot.errors import ProtocolError


def reference_crc(data: bytes) -> int:
    """CPython's CRC-CCITT (binascii.crc_hqx, poly 0x1021) with init 0: an independent implementation."""
    return binascii.crc_hqx(data, 0)


# ----- CRC ------------------------------------------------------------------------------------------
def test_crc_of_one_byte_worked_by_hand() -> None:
    # 0x80 << 8 = 0x8000; eight shifts, XOR 0x1021 whenever bit 15 falls out:
    # 0x1021, 0x2042, 0x4084, 0x8108, 0x1231, 0x2462, 0x48C4, 0x9188
    assert rc.crc16(b"\x80") == 0x9188


def test_crc_catalogue_check_values() -> None:
    assert rc.crc16(b"123456789") == 0x31C3  # CRC-16/XMODEM check value (the RoboClaw's parameters)
    assert rc.crc16(b"\xff") == 7920  # the value a third-party RoboClaw library asserts in its tests


@given(st.binary(max_size=64), st.binary(max_size=64))
def test_crc_matches_independent_implementation_and_chains(a: bytes, b: bytes) -> None:
    assert rc.crc16(a + b) == reference_crc(a + b)
    assert rc.crc16(b, rc.crc16(a)) == reference_crc(a + b)


# ----- host → controller bytes ------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("request_", "hex_bytes"),
    [
        # [0x80, 35, speed 1000 = 00 00 03 E8, CRC]
        (rc.drive_speed(0x80, 1, 1000), "80 23 00 00 03 e8 1b 33"),
        # command 36, -1000 in two's complement = FF FF FC 18
        (rc.drive_speed(0x80, 2, -1000), "80 24 ff ff fc 18 14 c7"),
        # command 40: [Accel, SpeedM1, SpeedM2] — accel is unsigned and comes first
        (rc.drive_speeds_accel(0x81, 6519, 1630, -815), "81 28 00 00 19 77 00 00 06 5e ff ff fc d1 ff 8e"),
        (rc.drive_speeds(0x80, 0, 0), "80 25 00 00 00 00 00 00 00 00 34 04"),
        # command 14: 0.1 s = one 100 ms unit
        (rc.set_serial_timeout(0x80, 0.1), "80 0e 01 08 74"),
        # reads send only address and command, no CRC
        (rc.read_encoder(0x81, 2), "81 11"),
        (rc.read_firmware_version(0x80), "80 15"),
    ],
)
def test_request_bytes(request_: rc.Request, hex_bytes: str) -> None:
    packet = request_.encode()
    assert packet == bytes.fromhex(hex_bytes)
    if not request_.is_read:
        assert int.from_bytes(packet[-2:], "big") == reference_crc(packet[:-2])


def test_speed_accel_single_channel_layout() -> None:
    packet = rc.drive_speed_accel(0x80, 2, -5, 100).encode()
    assert packet[:2] == bytes((0x80, 39))
    assert struct.unpack(">Ii", packet[2:10]) == (100, -5)


@pytest.mark.parametrize(
    "make",
    [
        lambda: rc.read_encoder(0x7F, 1),
        lambda: rc.read_encoder(0x88, 1),
        lambda: rc.drive_speed(0x80, 3, 0),
        lambda: rc.drive_speed(0x80, 1, 2**31),
        lambda: rc.drive_speed_accel(0x80, 1, 0, -1),
        lambda: rc.set_serial_timeout(0x80, 25.6),
    ],
)
def test_out_of_range_arguments_are_refused(make: object) -> None:
    with pytest.raises(ValueError):
        make()  # type: ignore[operator]


def test_serial_timeout_units_are_100_ms() -> None:
    assert rc.serial_timeout_value(0.1) == 1
    assert rc.serial_timeout_value(25.5) == 255
    assert rc.serial_timeout_value(0.0) == 0  # 0 disables the failsafe


# ----- controller → host replies -----------------------------------------------------------------------
def test_encoder_reply_decoded() -> None:
    # count 0x00012345 = 74565, status 0x02 (backwards), CRC over 80 10 00 01 23 45 02
    reply = replies.decode_reply(rc.read_encoder(0x80, 1), bytes.fromhex("00 01 23 45 02 ca 24"))
    assert reply == replies.EncoderCount(74565, 0x02)


def test_speed_reply_is_signed() -> None:
    reply = replies.decode_reply(rc.read_speed(0x80, 1), bytes.fromhex("ff ff f9 c0 01 50 87"))
    assert reply == replies.EncoderSpeed(-1600, 1)


def _reply(request: rc.Request, data: bytes) -> bytes:
    return data + reference_crc(bytes((request.address, request.command)) + data).to_bytes(2, "big")


def test_version_battery_and_timeout_replies() -> None:
    version = rc.read_firmware_version(0x80)
    text = replies.decode_reply(version, _reply(version, b"USB Roboclaw 2x15a v4.1.34\n\x00"))
    assert text == replies.FirmwareVersion("USB Roboclaw 2x15a v4.1.34")
    battery = rc.read_main_battery(0x81)
    assert replies.decode_reply(battery, _reply(battery, b"\x00\x78")) == replies.BatteryVoltage(12.0)
    timeout = rc.read_serial_timeout(0x80)
    assert replies.decode_reply(timeout, _reply(timeout, b"\x02")) == replies.SerialTimeout(0.2)


def test_ack_and_bad_ack() -> None:
    write = rc.reset_encoders(0x80)
    assert replies.decode_reply(write, b"\xff") == replies.Ack()
    with pytest.raises(ProtocolError, match="0xFF"):
        replies.decode_reply(write, b"\x00")


def test_byte_by_byte_feeding_and_leftovers() -> None:
    request = rc.read_encoder(0x80, 1)
    parser = replies.ReplyParser(request)
    data = bytes.fromhex("00 01 23 45 02 ca 24") + b"\x99"
    results = [parser.feed(data[i : i + 1]) for i in range(len(data))]
    assert results[:6] == [None] * 6
    assert results[6] == replies.EncoderCount(74565, 2)
    assert parser.unused == b"\x99"


def test_corrupt_truncated_and_overlong_replies() -> None:
    request = rc.read_encoder(0x80, 1)
    with pytest.raises(ProtocolError, match="CRC"):
        replies.decode_reply(request, bytes.fromhex("00 01 23 46 02 ca 24"))
    with pytest.raises(ProtocolError, match="truncated"):
        replies.decode_reply(request, bytes.fromhex("00 01 23 45 02 ca"))
    with pytest.raises(ProtocolError, match="unexpected"):
        replies.decode_reply(request, bytes.fromhex("00 01 23 45 02 ca 24 00"))
    with pytest.raises(ProtocolError, match="NUL"):
        replies.decode_reply(rc.read_firmware_version(0x80), b"x" * 60)


ALL_REQUESTS = [
    rc.read_encoder(0x80, 1),
    rc.read_speed(0x81, 2),
    rc.read_firmware_version(0x80),
    rc.read_main_battery(0x80),
    rc.read_serial_timeout(0x80),
    rc.drive_speeds(0x80, 1, 2),
]
FIXED_READS = [r for r in ALL_REQUESTS if r.is_read and replies.REPLY_DATA_SIZE[r.command] > 0]


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(ALL_REQUESTS), st.lists(st.binary(max_size=20), max_size=5))
def test_random_bytes_never_crash_nor_pass_unchecked(request_: rc.Request, chunks: list[bytes]) -> None:
    parser = replies.ReplyParser(request_)
    received = b""
    for chunk in chunks:
        received += chunk
        try:
            reply = parser.feed(chunk)
        except ProtocolError:
            return
        if reply is not None:
            consumed = received[: len(received) - len(parser.unused)]
            if request_.is_read:  # a value only ever comes with a CRC that checks out independently
                head = bytes((request_.address, request_.command))
                assert reference_crc(head + consumed[:-2]) == int.from_bytes(consumed[-2:], "big")
            else:
                assert consumed == b"\xff"
            return


@st.composite
def burst_or_odd_errors(draw: st.DrawFn, n_bits: int) -> int:
    """An error pattern CRC16-CCITT always detects: a burst of <= 16 bits, or an odd number of flips."""
    if draw(st.booleans()):
        length = draw(st.integers(1, min(16, n_bits)))
        start = draw(st.integers(0, n_bits - length))
        inner = draw(st.integers(0, 2 ** max(length - 2, 0) - 1)) if length > 2 else 0
        pattern = 1 | (inner << 1) | (1 << (length - 1))
        return pattern << start
    flips = draw(st.sets(st.integers(0, n_bits - 1), min_size=1, max_size=7).filter(lambda s: len(s) % 2 == 1))
    return sum(1 << bit for bit in flips)


@settings(max_examples=300)
@given(st.sampled_from(FIXED_READS), st.binary(min_size=5, max_size=5), st.data())
def test_corrupted_reply_is_a_crc_error_not_a_number(request_: rc.Request, value: bytes, data: st.DataObject) -> None:
    size = replies.REPLY_DATA_SIZE[request_.command]
    good = _reply(request_, value[:size])
    replies.decode_reply(request_, good)  # the uncorrupted reply decodes
    error = data.draw(burst_or_odd_errors(len(good) * 8))
    bad = (int.from_bytes(good, "big") ^ error).to_bytes(len(good), "big")
    with pytest.raises(ProtocolError):
        replies.decode_reply(request_, bad)


@given(st.integers(0, (len("USB Roboclaw 2x15a v4.1.34\n\x00") + 2) * 8 - 1))
def test_single_bit_flip_in_version_reply_never_gives_a_string(bit: int) -> None:
    request = rc.read_firmware_version(0x80)
    good = _reply(request, b"USB Roboclaw 2x15a v4.1.34\n\x00")
    bad = (int.from_bytes(good, "big") ^ (1 << bit)).to_bytes(len(good), "big")
    parser = replies.ReplyParser(request)
    with contextlib.suppress(ProtocolError):
        assert parser.feed(bad) is None  # NUL flipped away: still waiting, the driver times out


# ----- the controller's side -----------------------------------------------------------------------------
@pytest.mark.parametrize("request_", [*ALL_REQUESTS, rc.drive_speeds_accel(0x80, 9, -8, 7), rc.reset_encoders(0x87)])
def test_framer_round_trips_every_request(request_: rc.Request) -> None:
    packets = RequestFramer().feed(b"\x00\x13" + request_.encode(), now=0.0)  # leading noise is skipped
    assert packets == [Packet(request_.address, request_.command, request_.data)]


def test_framer_drops_bad_crc_and_stale_fragments() -> None:
    framer = RequestFramer()
    packet = rc.drive_speed(0x80, 1, 5).encode()
    assert framer.feed(packet[:-1] + bytes((packet[-1] ^ 1,)), now=0.0) == []
    assert framer.discarded == len(packet)
    assert framer.feed(packet[:3], now=1.0) == []
    assert framer.feed(packet[3:], now=1.011) == []  # > 10 ms between bytes: the fragment is discarded
    assert framer.feed(packet[:3], now=2.0) + framer.feed(packet[3:], now=2.005) != []


@settings(max_examples=200)
@given(st.lists(st.binary(max_size=24), max_size=6))
def test_framer_survives_noise_and_only_passes_checked_writes(chunks: list[bytes]) -> None:
    framer = RequestFramer()
    stream = b"".join(chunks)
    for i, chunk in enumerate(chunks):
        for packet in framer.feed(chunk, now=i * 0.001):
            head = bytes((packet.address, packet.command)) + packet.data
            if not packet.is_read:  # the packet, with an independently computed CRC, was really sent
                assert head + reference_crc(head).to_bytes(2, "big") in stream
            assert head in stream


def test_read_reply_encoding_is_what_the_host_parses() -> None:
    request = rc.read_speed(0x81, 1)
    assert replies.decode_reply(request, encode_read_reply(0x81, request.command, struct.pack(">iB", -7, 1))) == (
        replies.EncoderSpeed(-7, 1)
    )


# ----- the motor model and the emulator core (fake clock) -------------------------------------------------
def euler(tau: float, target: float, accel: float | None, t_end: float, dt: float = 1e-5) -> tuple[float, float]:
    """Independent check: integrate ramp + first-order lag numerically; (speed, position)."""
    v = x = s = 0.0
    for _ in range(round(t_end / dt)):
        s = target if accel is None else min(target, s + accel * dt)
        v += (s - v) / tau * dt
        x += v * dt
    return v, x


@pytest.mark.parametrize(("accel", "t_end"), [(None, 0.13), (5000.0, 0.13), (5000.0, 0.4)])
def test_motor_model_matches_numerical_integration(accel: float | None, t_end: float) -> None:
    motor = LaggedMotor(0.05, t=0.0)
    motor.command(0.0, 1000.0, accel)
    motor.advance(t_end / 3)
    motor.advance(t_end)  # split queries must not change the result
    v, x = euler(0.05, 1000.0, accel, t_end)
    assert motor.speed == pytest.approx(v, rel=1e-3)
    assert motor.position == pytest.approx(x, rel=1e-3)


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_emulator_drives_counts_and_answers_only_its_addresses() -> None:
    clock = FakeClock()
    emu = RoboClawEmulator(addresses=(128,), counts_per_rev=1024, clock=clock, time_constant_s=0.05)
    assert emu.receive(rc.drive_speed(0x80, 1, 2048).encode()) == b"\xff"
    assert emu.receive(rc.drive_speed(0x81, 1, 2048).encode()) == b""  # not ours: silence
    clock.t += 1.0
    expected = 2048 * (1.0 - 0.05 * (1 - math.exp(-1.0 / 0.05)))  # step response of a first-order lag
    reply = replies.decode_reply(rc.read_encoder(0x80, 1), emu.receive(rc.read_encoder(0x80, 1).encode()))
    assert isinstance(reply, replies.EncoderCount)
    assert reply.count == math.floor(expected)
    assert emu.motor_speed(128, 1) == pytest.approx(2 * math.pi * 2, rel=1e-6)  # 2048 counts/s = 2 rev/s


def test_emulator_failsafe_stops_at_last_byte_plus_timeout() -> None:
    clock = FakeClock()
    emu = RoboClawEmulator(clock=clock)
    assert emu.receive(rc.set_serial_timeout(0x80, 0.1).encode() + rc.set_serial_timeout(0x81, 0.2).encode())
    emu.receive(rc.drive_speeds(0x80, 500, -500).encode() + rc.drive_speed(0x81, 1, 300).encode())
    last_byte = clock.t
    clock.t += 0.5
    assert emu.commanded_speed(128, 1) == emu.commanded_speed(129, 1) == 0.0
    trips = {(e.address, e.channel): e.t for e in emu.command_log if e.source == "failsafe"}
    assert trips[(128, 1)] == pytest.approx(last_byte + 0.1)
    assert trips[(129, 1)] == pytest.approx(last_byte + 0.2)


def test_emulator_fault_injection() -> None:
    emu = RoboClawEmulator(clock=FakeClock())
    read = rc.read_encoder(0x80, 1)
    emu.drop_replies(1)
    assert emu.receive(read.encode()) == b""
    emu.corrupt_replies(1)
    with pytest.raises(ProtocolError):
        replies.decode_reply(read, emu.receive(read.encode()))
    emu.noisy_replies(1, length=3)
    assert len(emu.receive(read.encode())) == 3 + 7
    emu.stall()
    assert emu.receive(rc.drive_speed(0x80, 1, 100).encode()) == b""
    assert emu.commanded_speed(128, 1) == 0.0  # a stalled controller ignores commands
    emu.clear_faults()
    assert replies.decode_reply(read, emu.receive(read.encode())) == replies.EncoderCount(0, 0)
