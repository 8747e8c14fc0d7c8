"""The motor driver: wheel speeds (rad/s) in, encoder readings out, over RoboClaw packet serial.

Safety model. Any fault (no valid reply after the retries, a dead port) marks the driver
disconnected, immediately writes "both motors 0" to every controller, raises DriverError and starts
reconnecting with exponential backoff. Independently, each controller's serial-timeout failsafe
(command 14, armed at start) stops its motors when the host goes quiet — the only stop that works
when the cable is pulled. `safety.check_motors_config` refuses settings that cannot meet the 100 ms
fault-to-stop bound.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Awaitable, Callable, Mapping
from typing import TypeVar

import numpy as np

from gprbot.config import SIMULATED, MotorsConfig
from gprbot.drivers.health import DriverHealth, HealthTracker
from gprbot.drivers.motors import protocol as rc
from gprbot.drivers.motors import replies
from gprbot.drivers.motors.bus import LinkError, PacketBus, SupersededError
from gprbot.drivers.motors.encoders import CountUnwrapper
from gprbot.drivers.motors.safety import check_motors_config
from gprbot.errors import DriverError
from gprbot.messages import WheelEncoders, WheelSpeeds

RECONNECT_BACKOFF_S = (0.1, 2.0)  # first and longest wait between reconnection attempts
R = TypeVar("R")


class MotorDriver:
    """Three omni wheels on RoboClaw controllers; one request in flight per serial line.

    `ports` maps a controller address to its own serial port (controllers on separate USB ports);
    addresses not in it use `cfg.port` (controllers sharing one TTL line in multi-unit mode).
    """

    def __init__(
        self,
        cfg: MotorsConfig,
        clock: Callable[[], float] = time.monotonic,
        *,
        sleep: Callable[[float], Awaitable[None]] = asyncio.sleep,
        ports: Mapping[int, str] | None = None,
        backoff_s: tuple[float, float] = RECONNECT_BACKOFF_S,
    ) -> None:
        check_motors_config(cfg)
        self.cfg = cfg
        self._clock = clock
        self._sleep = sleep
        self._backoff_s = backoff_s
        self._addresses = sorted({address for address, _ in cfg.wheel_map})
        port_of = {a: (ports or {}).get(a, cfg.port) for a in self._addresses}
        self._buses = {
            url: PacketBus(url, cfg.baudrate, cfg.command_timeout_s, cfg.retries, self._bad_attempt, clock)
            for url in sorted(set(port_of.values()))
        }
        self._bus_of = {a: self._buses[port_of[a]] for a in self._addresses}
        self._counts_per_rad = cfg.encoder_counts_per_rev / (2 * math.pi)
        self._unwrappers = [CountUnwrapper() for _ in cfg.wheel_map]
        self.health_tracker = HealthTracker("motors")
        self.firmware: dict[int, str] = {}
        self.reconnects = 0
        self._connected = asyncio.Event()
        self._stop_generation = 0
        self._closing = False
        self._reconnect_task: asyncio.Task[None] | None = None

    # ----- lifecycle ----------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        """True while every controller answers."""
        return self._connected.is_set()

    async def start(self) -> None:
        """Open the port(s), check that each address is a RoboClaw, arm the failsafe, stop the wheels."""
        if any(url == SIMULATED for url in self._buses):
            raise DriverError(
                "motors.port is 'sim': serve a RoboClawEmulator on a pty (emulator.serve_pty()) and "
                "pass that path as motors.port"
            )
        self._closing = False
        await self._connect()

    async def close(self) -> None:
        """Stop the wheels (best effort), stop reconnecting and close the port(s)."""
        self._closing = True
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
            await asyncio.gather(self._reconnect_task, return_exceptions=True)
            self._reconnect_task = None
        if self.connected:
            with contextlib.suppress(DriverError):  # if it fails, the controllers' failsafe stops them
                await self.stop()
        self._disconnect()

    async def wait_connected(self) -> None:
        """Wait until the driver is (re)connected."""
        await self._connected.wait()

    def health(self) -> DriverHealth:
        """Connected flag, encoder read rate, errors and the last error."""
        return self.health_tracker.snapshot()

    # ----- commands -----------------------------------------------------------------------------
    async def set_wheel_speeds(self, ws: WheelSpeeds) -> None:
        """Command wheel speeds (rad/s, clamped to ±max_wheel_speed_rad_s), ramped at max_wheel_accel."""
        speeds = np.asarray(ws.speeds, dtype=np.float64)
        if speeds.shape != (len(self.cfg.wheel_map),):
            raise ValueError(f"expected {len(self.cfg.wheel_map)} wheel speeds, got shape {speeds.shape}")
        if not np.all(np.isfinite(speeds)):
            await self.stop()
            raise ValueError(f"non-finite wheel speed {speeds.tolist()}: wheels stopped")
        limit = self.cfg.max_wheel_speed_rad_s
        counts = [round(float(w) * self._counts_per_rad) for w in np.clip(speeds, -limit, limit)]
        accel = max(1, round(self.cfg.max_wheel_accel_rad_s2 * self._counts_per_rad))
        per_address: dict[int, dict[int, int]] = {}
        for (address, channel), value in zip(self.cfg.wheel_map, counts, strict=True):
            per_address.setdefault(address, {})[channel] = value
        generation = self._stop_generation

        def not_overtaken() -> bool:  # a stop() or a fault since this call began must not be undone
            return self._stop_generation == generation

        for address, channels in per_address.items():
            if len(channels) == 2:
                request = rc.drive_speeds_accel(address, accel, channels[1], channels[2])
            else:
                ((channel, value),) = channels.items()
                request = rc.drive_speed_accel(address, channel, value, accel)
            try:
                await self._transact(request, still_wanted=not_overtaken)
            except SupersededError:
                return

    async def stop(self) -> None:
        """Command every motor to 0 now, ahead of any queued request; DriverError if not confirmed."""
        self._stop_generation += 1
        self._require_connected()
        buses = list(self._buses.values())
        results = await asyncio.gather(
            *(bus.stop_all(self._stop_packets(bus)) for bus in buses), return_exceptions=True
        )
        for result in results:
            if isinstance(result, LinkError):
                raise await self._fault(str(result)) from result
            if isinstance(result, BaseException):
                raise result

    async def read_encoders(self) -> WheelEncoders:
        """Read every wheel's speed, back to back, then every count; t is when the last speed request left.

        Not when the replies were read: on a busy loop that is later by however long the loop was
        elsewhere, and the filter would place the wheels' motion late (the controller samples what it
        reports when the request reaches it, within a millisecond of its writing). Each speed keeps
        when its own request left (offsets from t), so the filter compares it with its velocity then."""
        n = len(self.cfg.wheel_map)
        counts = np.zeros(n, dtype=np.int64)
        speeds = np.zeros(n, dtype=np.float64)
        stamps = []
        for i, (address, channel) in enumerate(self.cfg.wheel_map):
            speed, sent = await self._read_timed(rc.read_speed(address, channel), replies.EncoderSpeed)
            stamps.append(sent)
            speeds[i] = speed.counts_per_s / self._counts_per_rad
        for i, (address, channel) in enumerate(self.cfg.wheel_map):
            count = await self._read(rc.read_encoder(address, channel), replies.EncoderCount)
            counts[i] = self._unwrappers[i].update(count.count)
        t = max(stamps)
        self.health_tracker.message(t)
        return WheelEncoders(t=t, counts=counts, speeds=speeds, speed_spread_s=t - min(stamps),
                             speed_offsets_s=np.array(stamps) - t)

    async def reset_encoders(self) -> None:
        """Zero the encoder counters of every controller (and the unwrapped counts)."""
        for address in self._addresses:
            await self._transact(rc.reset_encoders(address))
        for unwrapper in self._unwrappers:
            unwrapper.value = 0
            unwrapper.rebase(0)

    async def read_battery_voltage(self, address: int) -> float:
        """The main battery voltage (V) seen by the controller at `address`."""
        return (await self._read(rc.read_main_battery(address), replies.BatteryVoltage)).volts

    # ----- the request path and faults ------------------------------------------------------------
    async def _read(self, request: rc.Request, kind: type[R]) -> R:
        return (await self._read_timed(request, kind))[0]

    async def _read_timed(self, request: rc.Request, kind: type[R]) -> tuple[R, float]:
        reply, sent = await self._transact_timed(request)
        if not isinstance(reply, kind):
            raise DriverError(f"{request.describe()}: unexpected reply {reply!r}")  # a protocol-table bug
        return reply, sent

    async def _transact(
        self, request: rc.Request, still_wanted: Callable[[], bool] | None = None
    ) -> replies.Reply:
        return (await self._transact_timed(request, still_wanted))[0]

    async def _transact_timed(
        self, request: rc.Request, still_wanted: Callable[[], bool] | None = None
    ) -> tuple[replies.Reply, float]:
        self._require_connected()
        try:
            return await self._bus_of[request.address].exchange_timed(request, still_wanted=still_wanted)
        except LinkError as exc:
            raise await self._fault(str(exc)) from exc

    def _stop_packets(self, bus: PacketBus) -> list[rc.Request]:
        """Command 37 with both speeds 0 for every controller on `bus` (unmapped channels stop too)."""
        return [rc.drive_speeds(a, 0, 0) for a in self._addresses if self._bus_of[a] is bus]

    def _require_connected(self) -> None:
        if not self.connected:
            raise DriverError(
                f"motor controllers on {', '.join(self._buses)} are disconnected "
                f"(last error: {self.health_tracker.last_error}); reconnecting — the controllers' "
                f"{self.cfg.failsafe_timeout_s} s serial timeout has stopped the wheels"
            )

    def _bad_attempt(self, text: str) -> None:
        self.health_tracker.error(text)

    async def _fault(self, text: str) -> DriverError:
        """Stop everything we can reach, go disconnected, start reconnecting; the error to raise."""
        if self.connected:
            self._connected.clear()
            self._stop_generation += 1
            for bus in self._buses.values():
                bus.write_unlocked(self._stop_packets(bus))
            self.health_tracker.error(text)
            self._disconnect()
            if not self._closing:
                self._reconnect_task = asyncio.get_running_loop().create_task(self._reconnect())
        return DriverError(f"motor fault, wheels commanded to stop: {text}")

    def _disconnect(self) -> None:
        self._connected.clear()
        self.health_tracker.connected = False
        for bus in self._buses.values():
            bus.close()

    async def _reconnect(self) -> None:
        delay, longest = self._backoff_s
        while not self._closing:
            await self._sleep(delay)
            try:
                await self._connect()
            except DriverError as exc:
                self.health_tracker.error(f"reconnect failed: {exc}")
                delay = min(2 * delay, longest)
            else:
                self.reconnects += 1
                return

    async def _connect(self) -> None:
        try:
            for bus in self._buses.values():
                await bus.open()
            for address in self._addresses:
                self.firmware[address] = await self._identify(address)
            for bus in self._buses.values():
                await self._check_one_controller_per_address(bus)
            for address in self._addresses:
                await self._arm_failsafe(address)
            for bus in self._buses.values():
                await bus.stop_all(self._stop_packets(bus))
        except LinkError as exc:
            self._disconnect()
            raise DriverError(str(exc)) from exc
        except DriverError:
            self._disconnect()
            raise
        for unwrapper in self._unwrappers:
            unwrapper.rebase()
        self.health_tracker.connected = True
        self._connected.set()

    async def _identify(self, address: int) -> str:
        bus = self._bus_of[address]
        where = f"address {address} (0x{address:02X}) on {bus.url}"
        try:
            reply = await bus.exchange(rc.read_firmware_version(address))
        except LinkError as exc:
            if exc.port_error or exc.corrupt == 0:
                raise DriverError(
                    f"no RoboClaw answers at {where}: check that it is powered, in packet serial mode with "
                    f"this address and at {self.cfg.baudrate} baud (motors.baudrate) — {exc}"
                ) from exc
            raise DriverError(
                f"a device at {where} answers with corrupt replies: wrong baud rate "
                f"(motors.baudrate = {self.cfg.baudrate}) or not a RoboClaw — {exc}"
            ) from exc
        text = reply.text if isinstance(reply, replies.FirmwareVersion) else repr(reply)
        if "roboclaw" not in text.lower() and not text.lower().startswith("mcp"):
            raise DriverError(f"the device at {where} identifies as {text!r}, not a RoboClaw: check motors.port")
        return text

    async def _check_one_controller_per_address(self, bus: PacketBus) -> None:
        """Refuse two addresses that reach one controller: a USB port answers every address 0x80..0x87.

        Each address gets a different serial timeout; one controller behind several addresses reads
        back the last value written, so the earlier addresses see someone else's value.
        """
        addresses = [a for a in self._addresses if self._bus_of[a] is bus]
        if len(addresses) < 2:
            return
        for trial, address in enumerate(addresses, start=1):
            await bus.exchange(rc.set_serial_timeout(address, trial / 10))
        for trial, address in enumerate(addresses, start=1):
            reply = await bus.exchange(rc.read_serial_timeout(address))
            if not isinstance(reply, replies.SerialTimeout) or round(reply.timeout_s * 10) != trial:
                raise DriverError(
                    f"addresses {addresses} on {bus.url} reach the same controller (address {address} reads "
                    f"back another address's setting; over USB a RoboClaw answers every address): give each "
                    f"controller its own port, or wire them on one TTL line in multi-unit mode"
                )

    async def _arm_failsafe(self, address: int) -> None:
        bus = self._bus_of[address]
        await bus.exchange(rc.set_serial_timeout(address, self.cfg.failsafe_timeout_s))
        reply = await bus.exchange(rc.read_serial_timeout(address))
        wanted = rc.serial_timeout_value(self.cfg.failsafe_timeout_s) / 10
        if not isinstance(reply, replies.SerialTimeout) or reply.timeout_s != wanted:
            raise DriverError(
                f"the RoboClaw at address {address} on {bus.url} did not keep serial timeout {wanted} s "
                f"(reads back {reply}): update its firmware; without it the wheels may not stop on a fault"
            )
