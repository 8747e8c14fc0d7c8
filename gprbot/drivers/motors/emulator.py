"""RoboClaw emulator: one or more controllers on a shared packet-serial line, served on a pty.

The core (`receive`) is sans-IO: bytes in, reply bytes out, time from the injected clock. It frames
packets like the device, answers only its own addresses, drives each motor through `LaggedMotor`,
counts encoders, and honours the serial-timeout failsafe (command 14): when no byte arrives for the
set time both motors of every controller are commanded to 0, at exactly last-byte + timeout.
Fault injection: dropped replies, corrupted CRCs, noisy replies, a stalled controller, an unplugged
cable. `serve_pty()` exposes it to a driver as a serial device, served on the loop or (`threaded=True`)
in a thread of its own; one lock makes the controllers' state safe to read from either side.
"""

from __future__ import annotations

import math
import random
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from gprbot.drivers.motors.device_side import Packet, RequestFramer, encode_read_reply
from gprbot.drivers.motors.motor_model import LaggedMotor
from gprbot.drivers.motors.protocol import ACK, Cmd
from gprbot.drivers.motors.pty_link import PtyLink

DEFAULT_FIRMWARE = "USB Roboclaw 2x15a v4.1.34"
_WRAP = 2**32


@dataclass(frozen=True)
class MotorCommandEvent:
    """A speed target applied to one motor: by a serial command or by the failsafe."""

    t: float
    address: int
    channel: int
    counts_per_s: float
    source: str  # "serial" | "failsafe"


class _Controller:
    def __init__(self, address: int, time_constant_s: float, t: float) -> None:
        self.address = address
        self.motors = {1: LaggedMotor(time_constant_s, t), 2: LaggedMotor(time_constant_s, t)}
        self.serial_timeout_s = 0.0  # power-on default: failsafe off
        self.failsafe_tripped = False
        self.wraps_at_last_read = {1: 0, 2: 0}


class RoboClawEmulator:
    """Emulated RoboClaw controllers at `addresses`, with encoders of `counts_per_rev` counts/rev.

    `usb=True` emulates one controller on its own USB port, which answers every address.
    """

    def __init__(
        self,
        addresses: Iterable[int] = (128, 129),
        counts_per_rev: int = 1024,
        clock: Callable[[], float] = time.monotonic,
        *,
        firmware: str = DEFAULT_FIRMWARE,
        time_constant_s: float = 0.05,
        battery_v: float = 12.0,
        seed: int = 0,
        history: int = 10_000,
        usb: bool = False,
    ) -> None:
        self.counts_per_rev = counts_per_rev
        self.usb = usb  # over USB a controller answers every address 0x80..0x87 (manual, "Address")
        self.firmware = firmware
        self.battery_v = battery_v
        self._clock = clock
        now = clock()
        self._controllers = {a: _Controller(a, time_constant_s, now) for a in addresses}
        self._framer = RequestFramer()
        self._rng = random.Random(seed)
        self._last_rx: float | None = None
        self._command_log: deque[MotorCommandEvent] = deque(maxlen=history)
        self._lock = threading.RLock()  # the link's thread answers the host while the simulator reads motors
        self.packets_handled = 0
        self._drop = 0
        self._corrupt = 0
        self._noisy = 0
        self._noise_length = 6
        self.stalled = False
        self._link: PtyLink | None = None
        self._motion_step_s: float | None = None  # see record_motion
        self._motion_t = now
        self._motion: deque[tuple[float, tuple[float, ...]]] = deque(maxlen=history)

    @property
    def command_log(self) -> list[MotorCommandEvent]:
        """The speed targets applied so far (oldest first; a copy, safe while the link's thread runs)."""
        with self._lock:
            return list(self._command_log)

    # ----- sans-IO core ---------------------------------------------------------------------
    def receive(self, data: bytes) -> bytes:
        """Bytes from the host at clock(); returns the bytes the controllers send back."""
        with self._lock:
            return self._receive(data)

    def _receive(self, data: bytes) -> bytes:
        now = self._clock()
        self._advance(now)
        if self.stalled or not data:
            return b""
        self._last_rx = now
        for ctl in self._controllers.values():
            ctl.failsafe_tripped = False
        out = bytearray()
        for packet in self._framer.feed(data, now):
            controller = self._controllers.get(packet.address)
            if controller is None and self.usb:
                controller = next(iter(self._controllers.values()))
            if controller is None:
                continue  # another device's packet on the shared line
            self.packets_handled += 1
            out += self._apply_faults(self._handle(controller, packet, now))
        return bytes(out)

    def _handle(self, ctl: _Controller, packet: Packet, now: float) -> bytes:
        cmd, data = packet.command, packet.data
        if packet.is_read:
            return encode_read_reply(packet.address, cmd, self._read(ctl, cmd))
        if cmd in (Cmd.DRIVE_M1_SPEED, Cmd.DRIVE_M2_SPEED):
            self._drive(ctl, now, 1 if cmd == Cmd.DRIVE_M1_SPEED else 2, _i32(data, 0), None)
        elif cmd == Cmd.DRIVE_M1_M2_SPEED:
            self._drive(ctl, now, 1, _i32(data, 0), None)
            self._drive(ctl, now, 2, _i32(data, 4), None)
        elif cmd in (Cmd.DRIVE_M1_SPEED_ACCEL, Cmd.DRIVE_M2_SPEED_ACCEL):
            channel = 1 if cmd == Cmd.DRIVE_M1_SPEED_ACCEL else 2
            self._drive(ctl, now, channel, _i32(data, 4), _u32(data, 0))
        elif cmd == Cmd.DRIVE_M1_M2_SPEED_ACCEL:
            self._drive(ctl, now, 1, _i32(data, 4), _u32(data, 0))
            self._drive(ctl, now, 2, _i32(data, 8), _u32(data, 0))
        elif cmd == Cmd.RESET_ENCODERS:
            for channel, motor in ctl.motors.items():
                motor.position = 0.0
                ctl.wraps_at_last_read[channel] = 0
        elif cmd == Cmd.SET_SERIAL_TIMEOUT:
            ctl.serial_timeout_s = data[0] / 10.0
        return bytes((ACK,))

    def _read(self, ctl: _Controller, cmd: int) -> bytes:
        if cmd in (Cmd.READ_ENCODER_M1, Cmd.READ_ENCODER_M2):
            channel = 1 if cmd == Cmd.READ_ENCODER_M1 else 2
            motor = ctl.motors[channel]
            count = math.floor(motor.position)
            wraps = count // _WRAP
            previous = ctl.wraps_at_last_read[channel]
            ctl.wraps_at_last_read[channel] = wraps
            status = (0x01 if wraps < previous else 0) | (0x04 if wraps > previous else 0)
            status |= 0x02 if motor.speed < 0 else 0
            return struct.pack(">IB", count % _WRAP, status)
        if cmd in (Cmd.READ_SPEED_M1, Cmd.READ_SPEED_M2):
            speed = ctl.motors[1 if cmd == Cmd.READ_SPEED_M1 else 2].speed
            return struct.pack(">iB", round(speed), 1 if speed < 0 else 0)
        if cmd == Cmd.READ_FIRMWARE_VERSION:
            return self.firmware.encode("ascii") + b"\n\x00"
        if cmd == Cmd.READ_MAIN_BATTERY:
            return struct.pack(">H", round(self.battery_v * 10))
        return bytes((round(ctl.serial_timeout_s * 10),))  # READ_SERIAL_TIMEOUT

    def _drive(self, ctl: _Controller, t: float, channel: int, speed: int, accel: int | None) -> None:
        ctl.motors[channel].command(t, speed, accel)
        self._command_log.append(MotorCommandEvent(t, ctl.address, channel, float(speed), "serial"))

    def _advance(self, now: float) -> None:
        """Bring every motor to `now` (through the motion record's grid, when recording)."""
        step = self._motion_step_s
        if step is not None:
            while self._motion_t + step <= now:
                self._motion_t += step
                self._advance_to(self._motion_t)
                self._motion.append((self._motion_t, self._positions()))
        self._advance_to(now)

    def _positions(self) -> tuple[float, ...]:
        return tuple(m.position for ctl in self._controllers.values() for m in ctl.motors.values())

    def _advance_to(self, now: float) -> None:
        """Bring every motor to `now`, tripping the failsafe on the way if the line went quiet."""
        for ctl in self._controllers.values():
            if self._last_rx is None or ctl.failsafe_tripped or ctl.serial_timeout_s <= 0:
                continue
            trip = self._last_rx + ctl.serial_timeout_s
            if trip <= now:
                ctl.failsafe_tripped = True
                for channel, motor in ctl.motors.items():
                    motor.command(trip, 0.0)
                    self._command_log.append(MotorCommandEvent(trip, ctl.address, channel, 0.0, "failsafe"))
        for ctl in self._controllers.values():
            for motor in ctl.motors.values():
                motor.advance(now)

    # ----- motor state for the simulated robot and tests --------------------------------------
    def _motor(self, address: int, channel: int) -> LaggedMotor:
        self._advance(self._clock())
        return self._controllers[address].motors[channel]

    def motor_speed(self, address: int, channel: int) -> float:
        """The shaft speed now, in rad/s."""
        with self._lock:
            return self._motor(address, channel).speed * 2 * math.pi / self.counts_per_rev

    def commanded_speed(self, address: int, channel: int) -> float:
        """The speed target now (after any failsafe), in rad/s."""
        with self._lock:
            return self._motor(address, channel).target * 2 * math.pi / self.counts_per_rev

    def encoder_position(self, address: int, channel: int) -> float:
        """The encoder position now in counts (unwrapped, fractional)."""
        with self._lock:
            return self._motor(address, channel).position

    def encoder_positions(self, motors: Iterable[tuple[int, int]]) -> list[float]:
        """The encoder positions of several motors at one instant (counts, unwrapped, fractional)."""
        with self._lock:
            return [self._motor(address, channel).position for address, channel in motors]

    def record_motion(self, step_s: float) -> None:
        """From now on keep every motor's position on a grid of `step_s` (for the simulator's truth)."""
        with self._lock:
            self._motion_step_s, self._motion_t = step_s, self._clock()
            self._motion.clear()

    def motion_since(self, t: float, motors: Iterable[tuple[int, int]]) -> list[tuple[float, list[float]]]:
        """(time, positions in counts of `motors`) on the record's grid after t, then at the clock's now.

        The motors move between the host's requests whatever the host's loop does, and this is how
        they moved: the simulator integrates the true pose (and makes its IMU samples) from it, so a
        stalled loop changes when the truth is computed, never what it is."""
        wanted = list(motors)
        with self._lock:
            now = self._clock()
            self._advance(now)
            keys = [(a, c) for a, ctl in self._controllers.items() for c in ctl.motors]
            index = [keys.index(m) for m in wanted]
            out: list[tuple[float, list[float]]] = []
            for tm, positions in reversed(self._motion):  # newest first: only the few since t are read
                if tm <= t:
                    break
                out.append((tm, [positions[i] for i in index]))
            out.reverse()
            if now > t and (not out or out[-1][0] < now):
                out.append((now, [self._controllers[a].motors[c].position for a, c in wanted]))
            return out

    def set_encoder_position(self, address: int, channel: int, counts: float) -> None:
        """Move an encoder to `counts` (e.g. near the 32-bit wrap) without moving the motor."""
        with self._lock:
            self._motor(address, channel).position = counts
            self._controllers[address].wraps_at_last_read[channel] = math.floor(counts) // _WRAP

    def serial_timeout_s(self, address: int) -> float:
        """The failsafe timeout the host set on a controller (0: off)."""
        return self._controllers[address].serial_timeout_s

    # ----- fault injection -----------------------------------------------------------------------
    def drop_replies(self, count: int | None = None) -> None:
        """Execute commands but send no reply, for `count` replies (None: until clear_faults)."""
        self._drop = -1 if count is None else count

    def corrupt_replies(self, count: int | None = None) -> None:
        """Flip bits in the last byte (the CRC, or the 0xFF ack) of the next replies."""
        self._corrupt = -1 if count is None else count

    def noisy_replies(self, count: int | None = None, length: int = 6) -> None:
        """Prefix the next replies with `length` random bytes (line noise)."""
        self._noisy, self._noise_length = (-1 if count is None else count), length

    def stall(self) -> None:
        """The controller's serial handler hangs: bytes are ignored (the failsafe timer keeps running)."""
        self.stalled = True

    def clear_faults(self) -> None:
        """End every injected fault except an unplugged cable (see replug)."""
        self._drop = self._corrupt = self._noisy = 0
        self.stalled = False

    def inject_noise(self, length: int = 16) -> None:
        """Write `length` random bytes to the host right now."""
        if self._link is not None:
            self._link.write(self._random_bytes(length))

    def _apply_faults(self, reply: bytes) -> bytes:
        if self._drop:
            self._drop -= self._drop > 0
            return b""
        if self._corrupt:
            self._corrupt -= self._corrupt > 0
            reply = reply[:-1] + bytes((reply[-1] ^ 0x5A,))
        if self._noisy:
            self._noisy -= self._noisy > 0
            reply = self._random_bytes(self._noise_length) + reply
        return reply

    def _random_bytes(self, length: int) -> bytes:
        return bytes(self._rng.randrange(256) for _ in range(length))

    # ----- the serial line ---------------------------------------------------------------------------
    def serve_pty(self, link_path: str | Path | None = None, *, threaded: bool = False) -> str:
        """Serve on a new pty (on the running loop, or in a thread); returns the device path (or `link_path`)."""
        if self._link is None:
            self._link = PtyLink(self.receive, link_path, threaded=threaded)
        return self._link.open()

    def unplug(self) -> None:
        """Pull the cable: the pty hangs up; the controllers keep running on their own failsafe."""
        if self._link is not None:
            self._link.close()

    def replug(self) -> str:
        """Plug back in: a new pty behind the same symlink (as udev does); returns the path."""
        if self._link is None:
            raise RuntimeError("serve_pty() was never called")
        return self._link.open()

    def close(self) -> None:
        """Stop serving (same as unplug)."""
        self.unplug()


def _i32(data: bytes, offset: int) -> int:
    return int(struct.unpack_from(">i", data, offset)[0])


def _u32(data: bytes, offset: int) -> int:
    return int(struct.unpack_from(">I", data, offset)[0])
