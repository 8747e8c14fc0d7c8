"""An emulator of the SPIDAR NIC-500 in SDK mode on loopback: the same HTTP API and data socket, with faults.

Its HTTP API lives in `emulator_api`. Where the vendor's docs are silent: one data client at a time (a new
one replaces the old), and traces requested while no client is connected are lost (their numbers still
advance, so a reader sees a gap).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprDeviceConfig
from gprbot.drivers.gpr.emulator_api import (
    ALREADY_RUNNING,
    BAD_FORMAT,
    MODIFIED_INPUT,
    NOT_INITIALISED,
    NOT_POWERED,
    NOT_RUNNING,
    NOT_SUPPORTED,
    OUT_OF_RANGE,
    EmulatedSdkApi,
    Reply,
    check_setup,
)
from gprbot.drivers.gpr.sdk_api import ACQUISITION_START, ACQUISITION_STOP, API_IDENTITY, AcquisitionSetup
from gprbot.drivers.gpr.trace_stream import encode_frame

__all__ = [
    "ALREADY_RUNNING", "BAD_FORMAT", "MODIFIED_INPUT", "NOT_INITIALISED", "NOT_POWERED", "NOT_RUNNING",
    "NOT_SUPPORTED", "OUT_OF_RANGE", "GprSdkEmulator", "Reply", "TraceSource", "check_setup",
]

TraceSource = Callable[[int], NDArray[np.float32]]


class GprSdkEmulator(EmulatedSdkApi):
    """A NIC-500 in SDK mode on loopback; trace_source(n) gives the samples (mV) of trace n.

    trace_source is called when trace n is requested (so a simulator can use the robot's pose then);
    its samples are cut or zero-padded to the setup's points_per_trace. Ports 0 pick free ones (see
    `http_port`, `data_port` once started). `rate_hz` None follows the setup's trigger period, like
    the device. `enforce_device_ranges` applies the documented parameter ranges and resolutions (the
    simulated 23.4375 ps sampling is finer than a real NIC allows). Fault methods act on the stream.
    """

    def __init__(
        self,
        trace_source: TraceSource,
        host: str = "127.0.0.1",
        http_port: int = 0,
        data_port: int = 0,
        rate_hz: float | None = None,
        *,
        device_clock: Callable[[], float] = time.time,
        identity: str = API_IDENTITY,
        window_shift_reference_ps: float | None = -45000.0,
        enforce_device_ranges: bool = True,
    ):
        self.trace_source = trace_source
        self.host = host
        self.rate_hz = rate_hz
        self.device_clock = device_clock
        self.identity = identity
        self.window_shift_reference_ps = window_shift_reference_ps
        self.enforce_device_ranges = enforce_device_ranges
        self._ports = [http_port, data_port]
        self._servers: list[asyncio.Server] = []
        self._client: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self.power_state = 1
        self.acquisition_state = ACQUISITION_STOP
        self.setup: AcquisitionSetup | None = None
        self.last_number = 0
        self.frames_sent = 0
        self.requests: list[tuple[str, str]] = []  # (method, resource) in order, for tests
        self._noise: tuple[bytes, bool] | None = None
        self._unplug_mid_frame: bool | None = None
        self._stalled = False
        self._skip = 0
        self._rejections: list[tuple[int, int]] = []  # (status code, HTTP status) for coming setups
        self._wake = asyncio.Event()  # set when acquisition may resume

    @property
    def http_port(self) -> int:
        """The bound HTTP port."""
        return self._ports[0]

    @property
    def data_port(self) -> int:
        """The bound data socket port."""
        return self._ports[1]

    def driver_config(self, base: GprDeviceConfig | None = None) -> GprDeviceConfig:
        """`base` (or the defaults) pointed at this emulator."""
        return dataclasses.replace(base or GprDeviceConfig(), host=self.host, http_port=self.http_port,
                                   data_port=self.data_port)

    async def start(self) -> None:
        """Listen on both ports and start the acquisition loop."""
        await self._listen()
        self._task = asyncio.create_task(self._acquire(), name="gpr-emulator")

    async def stop(self) -> None:
        """Stop listening and acquiring; close any client."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        await self.go_offline()

    async def __aenter__(self) -> GprSdkEmulator:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # ---- faults ---------------------------------------------------------------------------------

    def unplug(self, mid_frame: bool = True) -> None:
        """Cut the data connection at the next trace, after half of it if `mid_frame`."""
        self._unplug_mid_frame = mid_frame

    async def go_offline(self) -> None:
        """The cable is out: both ports refuse connections and the data client is cut."""
        for server in self._servers:
            server.close()
            await server.wait_closed()
        self._servers = []
        self._drop_client()

    async def come_online(self) -> None:
        """The cable is back: listen again on the same ports."""
        if not self._servers:
            await self._listen()

    def inject_noise(self, n_bytes: int, inside_frame: bool = False, seed: int = 0) -> None:
        """Send `n_bytes` random bytes before the next trace, or in the middle of it."""
        noise = np.random.default_rng(seed).integers(0, 256, n_bytes, dtype=np.uint8).tobytes()
        self._noise = (noise, inside_frame)

    def stall(self) -> None:
        """Stop producing traces, keeping the connection open (`resume()` ends it)."""
        self._stalled = True

    def resume(self) -> None:
        """End a stall."""
        self._stalled = False
        self._wake.set()

    def skip_numbers(self, count: int) -> None:
        """The next trace number jumps by `count` (those traces are never sent)."""
        self._skip += count

    def reject_setup(self, times: int = 1, status_code: int = OUT_OF_RANGE, http_status: int = 400) -> None:
        """Answer the next `times` setup requests with an error."""
        self._rejections += [(status_code, http_status)] * times

    def power_cycle(self) -> None:
        """The NIC reboots: acquisition stopped, GPR off, setup and numbering lost, data client cut."""
        self._drop_client()
        self.power_state, self.acquisition_state, self.setup, self.last_number = 1, ACQUISITION_STOP, None, 0

    # ---- sockets (the HTTP handlers are in EmulatedSdkApi) --------------------------------------

    async def _listen(self) -> None:
        http = await asyncio.start_server(self._serve_http, self.host, self._ports[0])
        data = await asyncio.start_server(self._serve_data, self.host, self._ports[1])
        self._servers = [http, data]
        self._ports = [s.sockets[0].getsockname()[1] for s in self._servers]

    async def _serve_data(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._drop_client()
        self._client = writer
        with contextlib.suppress(ConnectionError):
            while await reader.read(4096):  # nothing is expected from the client; wait for it to go
                pass
        if self._client is writer:
            self._client = None
        writer.close()
        with contextlib.suppress(OSError):
            await writer.wait_closed()

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.transport.abort()
            self._client = None

    async def _acquire(self) -> None:
        loop = asyncio.get_running_loop()
        next_t = loop.time()
        while True:
            setup = self.setup
            if self.acquisition_state != ACQUISITION_START or self._stalled or setup is None:
                self._wake.clear()
                await self._wake.wait()
                next_t = loop.time()
                continue
            next_t += 1.0 / self.rate_hz if self.rate_hz else setup.period_s
            delay = next_t - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                await asyncio.sleep(0)  # catching up: still let the rest of the loop run between frames
            if delay < -1.0:  # fell far behind (a blocked loop): carry on without a burst
                next_t = loop.time()
            if self.acquisition_state != ACQUISITION_START or self._stalled or self.setup is not setup:
                continue
            self.last_number += 1 + self._skip
            self._skip = 0
            await self._send(self._frame(self.last_number, setup))

    def _frame(self, number: int, setup: AcquisitionSetup) -> bytes:
        # Stamped when it is recorded, as the NIC does, not once the source has computed it: the simulator's
        # source takes the antenna's position at this call and needs milliseconds (tens on a loaded
        # machine), so a later stamp tagged every trace with a pose further along its line.
        stamp = self.device_clock()
        samples = np.asarray(self.trace_source(number), dtype=np.float32).ravel()[: setup.points_per_trace]
        if samples.size < setup.points_per_trace:  # the source is shorter than the setup: pad with zeros
            samples = np.pad(samples, (0, setup.points_per_trace - samples.size))
        seconds = int(stamp // 1)
        nanos = min(round((stamp - seconds) * 1e9), 999_999_999)
        return encode_frame(number, samples, seconds, nanos, setup.point_stacks)

    async def _send(self, frame: bytes) -> None:
        writer = self._client
        if writer is None or writer.is_closing():
            return  # no client: the trace is lost, its number still used
        if self._unplug_mid_frame is not None:
            writer.write(frame[: len(frame) // 2] if self._unplug_mid_frame else frame)
            self._unplug_mid_frame = None
            with contextlib.suppress(ConnectionError, TimeoutError):
                async with asyncio.timeout(1.0):
                    await writer.drain()
            self._drop_client()  # abort: no orderly close, as when a cable is pulled
            return
        if self._noise is not None:
            noise, inside = self._noise
            self._noise = None
            half = len(frame) // 2
            frame = frame[:half] + noise + frame[half:] if inside else noise + frame
        writer.write(frame)
        self.frames_sent += 1
        try:
            async with asyncio.timeout(1.0):  # a client that stopped reading is dropped
                await writer.drain()
        except (ConnectionError, TimeoutError):
            if self._client is writer:
                self._drop_client()
