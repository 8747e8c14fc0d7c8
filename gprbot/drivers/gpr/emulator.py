"""An emulator of the SPIDAR NIC-500 in SDK mode on loopback: the same HTTP API and data socket, with faults.

It follows the vendor's documented behaviour (resources, status codes, parameter ranges and
resolutions of api/nic/setup, numbering from 1 after each setup). Where the docs are silent: errors are
answered with HTTP 400 (404 for an unknown resource) as well as their status code, one data client at
a time (a new one replaces the old), and traces requested while no client is connected are lost (their
numbers still advance, so a reader sees a gap).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qs

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprDeviceConfig
from gprbot.drivers.gpr.protocol import (
    ACQUISITION_START,
    ACQUISITION_STOP,
    API_IDENTITY,
    POWER_ALL_ON,
    RESOURCE_ACQUISITION,
    RESOURCE_DATA_SOCKET,
    RESOURCE_DATA_SOCKET_RESET,
    RESOURCE_GPR_INFO,
    RESOURCE_NIC_INFO,
    RESOURCE_POWER,
    RESOURCE_ROOT,
    RESOURCE_SETUP,
    RESOURCE_STATUS,
    VALID_STACKS,
    AcquisitionSetup,
    encode_frame,
    setup_payload,
)

TraceSource = Callable[[int], NDArray[np.float32]]
Reply = tuple[int, dict[str, Any]]

# Status codes of the vendor's docs.
OUT_OF_RANGE, NOT_SUPPORTED, BAD_FORMAT = 8, 9, 11
NOT_POWERED, NOT_RUNNING, ALREADY_RUNNING, NOT_INITIALISED = 4001, 4003, 4004, 4005
MODIFIED_INPUT = 913


def _envelope(resource: str, data: Any, code: int = 0, message: str = "The command executed successfully") -> Reply:
    kind = "SUCCESS" if code == 0 else "WARNING" if 900 <= code < 1000 else "ERROR"
    http = 200 if kind != "ERROR" else 404 if code == NOT_SUPPORTED else 400
    status = {"status_code": code, "message": message, "type": kind, "source": resource.removeprefix("/api/")}
    return http, {"status": status, "message": message, "data": data, "success": kind != "ERROR"}


def check_setup(setup: AcquisitionSetup, enforce_ranges: bool) -> tuple[AcquisitionSetup, int, str]:
    """The setup the NIC applies: (setup, 0 or 913 when rounded, message), or a (setup, 8, why) error."""
    problems = []
    if setup.trigger_mode not in ("Free", "Pulse"):
        problems.append(f"trigger_mode {setup.trigger_mode!r}")
    if setup.point_stacks not in VALID_STACKS:
        problems.append(f"point_stacks {setup.point_stacks}")
    if not enforce_ranges:
        if setup.points_per_trace < 1 or setup.time_sampling_interval_ps <= 0 or setup.period_s <= 0:
            problems.append("non-positive points_per_trace, time_sampling_interval_ps or period_s")
        return (setup, OUT_OF_RANGE, "; ".join(problems)) if problems else (setup, 0, "ok")
    if not 70 <= setup.points_per_trace <= 30000:
        problems.append(f"points_per_trace {setup.points_per_trace} not in 70..30000")
    if not 50 <= setup.time_sampling_interval_ps <= 6400:
        problems.append(f"time_sampling_interval_ps {setup.time_sampling_interval_ps} not in 50..6400")
    if not -50_000_000 <= setup.window_time_shift_ps <= 50_000_000:
        problems.append(f"window_time_shift_ps {setup.window_time_shift_ps} out of range")
    if not 0.00125 <= setup.period_s <= 60:
        problems.append(f"period_s {setup.period_s} not in 0.00125..60")
    if problems:
        return setup, OUT_OF_RANGE, "Value out of range: " + "; ".join(problems)
    rounded = dataclasses.replace(
        setup,
        time_sampling_interval_ps=float(50 * round(setup.time_sampling_interval_ps / 50)),
        window_time_shift_ps=float(5 * round(setup.window_time_shift_ps / 5)),
    )
    if rounded != setup:
        return rounded, MODIFIED_INPUT, "Modified Input: rounded to the closest valid value"
    return setup, 0, "ok"


class GprSdkEmulator:
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

    # ---- HTTP -----------------------------------------------------------------------------------

    async def _listen(self) -> None:
        http = await asyncio.start_server(self._serve_http, self.host, self._ports[0])
        data = await asyncio.start_server(self._serve_data, self.host, self._ports[1])
        self._servers = [http, data]
        self._ports = [s.sockets[0].getsockname()[1] for s in self._servers]

    async def _serve_http(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = (await reader.readuntil(b"\r\n\r\n")).decode("latin-1").split("\r\n")
            method, target, _version = head[0].split(" ", 2)
            headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in head[1:] if line)}
            body = await reader.readexactly(int(headers.get("content-length", "0")))
            status, doc = self._dispatch(method, target.split("?")[0].rstrip("/") or "/", body)
            payload = json.dumps(doc).encode()
            writer.write(f"HTTP/1.1 {status} {'OK' if status == 200 else 'Error'}\r\nContent-Type: application/json"
                         f"\r\nContent-Length: {len(payload)}\r\nConnection: close\r\n\r\n".encode() + payload)
            await writer.drain()
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ValueError, ConnectionError):
            pass  # a malformed request or a client gone: close, as a small embedded server would
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()

    def _dispatch(self, method: str, resource: str, body: bytes) -> Reply:
        self.requests.append((method, resource))
        if method == "GET":
            getters: dict[str, Callable[[], Reply]] = {
                RESOURCE_ROOT: lambda: _envelope(resource, {"name": self.identity, "version": "emulated"}),
                RESOURCE_NIC_INFO: lambda: _envelope(resource, {"nic_serial_number": "EMULATED", "app_version": "sim"}),
                RESOURCE_GPR_INFO: self._gpr_info,
                RESOURCE_POWER: lambda: _envelope(resource, {"state": self.power_state}),
                RESOURCE_SETUP: lambda: _envelope(resource, self._setup_data()),
                RESOURCE_ACQUISITION: lambda: _envelope(resource, {"state": self.acquisition_state}),
                RESOURCE_STATUS: lambda: _envelope(resource, {"processor": {"temperature_c": 40.0},
                                                              "power": {"input_voltage": 12.0}}),
                RESOURCE_DATA_SOCKET: lambda: _envelope(resource, {"data_socket": {"port": self.data_port}}),
            }
            if resource in getters:
                return getters[resource]()
        elif method == "PUT" and resource in (RESOURCE_POWER, RESOURCE_SETUP, RESOURCE_ACQUISITION,
                                              RESOURCE_DATA_SOCKET_RESET):
            try:
                fields = parse_qs(body.decode("utf-8"), keep_blank_values=True)
                payload = json.loads(fields["data"][0]) if "data" in fields else {}
            except (ValueError, KeyError):
                return _envelope(resource, None, BAD_FORMAT, "Invalid Input Parameter Format")
            if not isinstance(payload, dict):
                return _envelope(resource, None, BAD_FORMAT, "Invalid Input Parameter Format")
            if resource == RESOURCE_POWER:
                return self._put_power(payload)
            if resource == RESOURCE_SETUP:
                return self._put_setup(payload)
            if resource == RESOURCE_ACQUISITION:
                return self._put_acquisition(payload)
            self._drop_client()
            return _envelope(resource, {})
        return _envelope(resource, None, NOT_SUPPORTED, "The requested command is not supported")

    def _gpr_info(self) -> Reply:
        if self.power_state != POWER_ALL_ON:
            return _envelope(RESOURCE_GPR_INFO, None, NOT_POWERED, "GPR Not Powered")
        gpr = {"unit_serial_number": "EMULATED", "app_code_version": "sim",
               "window_time_shift_reference_ps": self.window_shift_reference_ps}
        return _envelope(RESOURCE_GPR_INFO, {"gpr": gpr})

    def _setup_data(self) -> dict[str, Any]:
        return setup_payload(self.setup) if self.setup is not None else {}

    def _put_power(self, payload: dict[str, Any]) -> Reply:
        state = payload.get("state")
        if state not in (0, 1, 2):
            return _envelope(RESOURCE_POWER, None, OUT_OF_RANGE, "Value Out Of Range")
        self.power_state = int(state)  # 0 (NIC off) is accepted but not modelled beyond the state
        return _envelope(RESOURCE_POWER, {"state": self.power_state})

    def _put_setup(self, payload: dict[str, Any]) -> Reply:
        if self._rejections:
            code, http = self._rejections.pop(0)
            return http, _envelope(RESOURCE_SETUP, None, code, "Setup rejected (injected fault)")[1]
        if self.power_state != POWER_ALL_ON:
            return _envelope(RESOURCE_SETUP, None, NOT_POWERED, "GPR Not Powered")
        if self.acquisition_state != ACQUISITION_STOP:
            return _envelope(RESOURCE_SETUP, None, ALREADY_RUNNING, "GPR Already Running")
        gpr = payload.get("gpr0", payload.get("gpr", {}))
        timer = payload.get("timer", {})
        if not isinstance(gpr, dict) or not isinstance(timer, dict) or not gpr.keys() <= {"parameters"} \
                or not timer.keys() <= {"parameters"}:
            return _envelope(RESOURCE_SETUP, None, BAD_FORMAT, "Invalid Input Parameter Format")
        current = setup_payload(self.setup or AcquisitionSetup(100, 100.0, 1, -48000.0, 1.0))
        merged = {**current["gpr0"]["parameters"], **gpr.get("parameters", {})}
        period = {**current["timer"]["parameters"], **timer.get("parameters", {})}["period_s"]
        try:
            requested = AcquisitionSetup(int(merged["points_per_trace"]), float(merged["time_sampling_interval_ps"]),
                                         int(merged["point_stacks"]), float(merged["window_time_shift_ps"]),
                                         float(period), str(merged["trigger_mode"]))
        except (TypeError, ValueError):
            return _envelope(RESOURCE_SETUP, None, BAD_FORMAT, "Invalid Input Parameter Format")
        applied, code, message = check_setup(requested, self.enforce_device_ranges)
        if code == OUT_OF_RANGE:
            return _envelope(RESOURCE_SETUP, None, code, message)
        self.setup, self.last_number = applied, 0  # a setup resets the numbering to 1
        if code:
            return _envelope(RESOURCE_SETUP, self._setup_data(), code, message)
        return _envelope(RESOURCE_SETUP, self._setup_data())

    def _put_acquisition(self, payload: dict[str, Any]) -> Reply:
        state = payload.get("state")
        if state not in (0, 1, 2):
            return _envelope(RESOURCE_ACQUISITION, None, BAD_FORMAT, "Invalid Parameter Format")
        if self.power_state != POWER_ALL_ON:
            return _envelope(RESOURCE_ACQUISITION, None, NOT_POWERED, "GPR Not Powered")
        running = self.acquisition_state == ACQUISITION_START
        if state == ACQUISITION_START and running:
            return _envelope(RESOURCE_ACQUISITION, None, ALREADY_RUNNING, "GPR Already Running")
        if state == ACQUISITION_START and self.setup is None:
            return _envelope(RESOURCE_ACQUISITION, None, NOT_INITIALISED, "GPR Not Initialized")
        if state != ACQUISITION_START and not running:
            return _envelope(RESOURCE_ACQUISITION, None, NOT_RUNNING, "GPR Not Running")
        self.acquisition_state = int(state)
        if state == ACQUISITION_STOP:
            self.last_number = 0
        self._wake.set()
        return _envelope(RESOURCE_ACQUISITION, {"state": self.acquisition_state})

    # ---- data socket ----------------------------------------------------------------------------

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
            elif delay < -1.0:  # fell far behind (a blocked loop): carry on without a burst
                next_t = loop.time()
            if self.acquisition_state != ACQUISITION_START or self._stalled or self.setup is not setup:
                continue
            self.last_number += 1 + self._skip
            self._skip = 0
            await self._send(self._frame(self.last_number, setup))

    def _frame(self, number: int, setup: AcquisitionSetup) -> bytes:
        samples = np.asarray(self.trace_source(number), dtype=np.float32).ravel()[: setup.points_per_trace]
        if samples.size < setup.points_per_trace:  # the source is shorter than the setup: pad with zeros
            samples = np.pad(samples, (0, setup.points_per_trace - samples.size))
        stamp = self.device_clock()
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
