"""Asyncio driver of the SPIDAR NIC-500 in SDK mode: control over HTTP/JSON, traces from the data socket.

The driver only moves bytes and converts time; framing lives in `trace_stream`, the API's JSON and the
mapping of the config to the NIC's setup in `sdk_api`, the HTTP client and the clock in `sdk_client`.
Once started it keeps itself alive: when either socket drops or the stream stalls it reconnects with
exponential backoff, re-running the setup only if the NIC stopped acquiring (a power cycle). Traces
already queued are never lost, and numbers never repeat.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import time
from collections.abc import AsyncGenerator, Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from gprbot.backoff import Backoff
from gprbot.config import SIMULATED, GprDeviceConfig
from gprbot.drivers.gpr import sdk_api as api
from gprbot.drivers.gpr.raw_replay import trace_of
from gprbot.drivers.gpr.sdk_client import READ_CHUNK, NicClock, SdkHttpClient
from gprbot.drivers.gpr.trace_stream import (
    DuplicateTrace,
    Resync,
    TraceCounter,
    TraceEvent,
    TraceFrame,
    TraceGap,
    TraceStreamParser,
)
from gprbot.drivers.health import DriverHealth, HealthTracker
from gprbot.errors import DriverError, GprbotError, ProtocolError
from gprbot.messages import GprRawChunk, GprStreamSetup, Trace

__all__ = [
    "BACKOFF_INITIAL_S",
    "BACKOFF_MAX_S",
    "MIN_STALL_TIMEOUT_S",
    "QUEUE_SIZE",
    "READ_CHUNK",
    "STALL_PERIODS",
    "GprDriver",
    "GprLinkStats",
    "NicClock",
    "SdkHttpClient",
    "Sleep",
]

Sleep = Callable[[float], Awaitable[None]]

BACKOFF_INITIAL_S = 0.1
BACKOFF_MAX_S = 5.0
QUEUE_SIZE = 1024  # traces buffered for a slow consumer; beyond it TCP backpressure reaches the NIC
# With no explicit stall timeout: this many trigger periods, but never less than MIN_STALL_TIMEOUT_S.
STALL_PERIODS = 50
MIN_STALL_TIMEOUT_S = 1.0


@dataclass(frozen=True)
class GprLinkStats:
    """Counters of the GPR link beyond DriverHealth: what was lost, skipped and recovered."""

    traces: int
    drops: int
    duplicates: int
    resyncs: int
    bytes_skipped: int
    reconnects: int
    stalls: int
    clock_jumps: int


class GprDriver:
    """The SPIDAR NIC-500 driver (the drivers' contract): `start()`, iterate `traces()`, `health()`, `close()`.

    Trace numbers are the NIC's until it restarts its numbering (a setup after a power cycle); from then
    on they continue from the last delivered number, so they always increase. `t0_ns` is where the first
    break lies in each trace (see `sdk_api.setup_from_config`). `clock` gives host receive times,
    `sleep` paces the reconnect backoff, `raw_sink` gets a GprStreamSetup as each connection's parser
    starts and a GprRawChunk per data-socket read (the run log's record of the raw stream).
    """

    def __init__(
        self,
        cfg: GprDeviceConfig,
        clock: Callable[[], float] = time.monotonic,
        *,
        sleep: Sleep = asyncio.sleep,
        stall_timeout_s: float | None = None,
        backoff_initial_s: float = BACKOFF_INITIAL_S,
        backoff_max_s: float = BACKOFF_MAX_S,
        raw_sink: Callable[[GprStreamSetup | GprRawChunk], None] | None = None,
    ):
        self.cfg = cfg
        self._raw_sink = raw_sink  # every data-socket read and each connection's setup, for the run log
        self._session = 0
        self._clock = clock
        self._sleep = sleep
        self._stall_timeout_s = (stall_timeout_s or cfg.stall_timeout_s
                                 or max(MIN_STALL_TIMEOUT_S, STALL_PERIODS * cfg.trigger_period_s))
        self._backoff = (backoff_initial_s, backoff_max_s)
        self._http = SdkHttpClient(cfg.host, cfg.http_port, cfg.connect_timeout_s)
        self._health = HealthTracker("gpr")
        self._counter = TraceCounter()
        self._device_clock = NicClock()
        self._queue: asyncio.Queue[Trace | None] = asyncio.Queue(QUEUE_SIZE)
        self._parser: TraceStreamParser | None = None
        self._data: tuple[asyncio.StreamReader, asyncio.StreamWriter] | None = None
        self._task: asyncio.Task[None] | None = None
        self._stopping = False
        self._stopped = False
        self._counts = {"traces": 0, "resyncs": 0, "bytes_skipped": 0, "reconnects": 0, "stalls": 0}
        self.setup: api.AcquisitionSetup | None = None  # as the NIC applied it
        self.device_info: dict[str, Any] = {}
        self._t0_ns = 0.0

    async def start(self) -> None:
        """Check the device, power it, set it up, start acquiring and open the data socket."""
        if self.cfg.host == SIMULATED:
            raise DriverError("gpr_device.host is 'sim': start GprSdkEmulator and use emulator.driver_config(cfg)")
        if self._task is not None:
            raise DriverError("the GPR driver is already started")
        try:
            await self._configure()
        except ProtocolError as exc:
            raise DriverError(f"the NIC at {self._http.url} sent a malformed reply: {exc}") from exc
        finally:
            if not self._health.connected:
                await self._close_data()
        self._task = asyncio.create_task(self._run(), name="gpr-driver")

    async def close(self) -> None:
        """Stop the link and the NIC's acquisition; `traces()` ends after the queued traces."""
        self._stopping = True
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        await self._close_data(wait=False)
        try:
            await self._http.put(api.RESOURCE_ACQUISITION, {"state": api.ACQUISITION_STOP})
        except DriverError as exc:
            self._health.error(f"could not stop the acquisition: {exc}")
        self._stopped = True
        with contextlib.suppress(asyncio.QueueFull):  # a full queue: traces() sees _stopped once drained
            self._queue.put_nowait(None)

    async def traces(self) -> AsyncGenerator[Trace, None]:
        """The received traces, in order, until `close()`."""
        while not (self._stopped and self._queue.empty()):
            trace = await self._queue.get()
            if trace is None:
                return
            yield trace

    def health(self) -> DriverHealth:
        """Connected, rate, drops (missing trace numbers), errors and the last one."""
        return self._health.snapshot()

    def stats(self) -> GprLinkStats:
        """The link's counters since construction."""
        parser = self._parser
        return GprLinkStats(
            traces=self._counts["traces"],
            drops=self._counter.drops,
            duplicates=self._counter.duplicates,
            resyncs=self._counts["resyncs"] + (parser.resyncs if parser else 0),
            bytes_skipped=self._counts["bytes_skipped"] + (parser.bytes_skipped if parser else 0),
            reconnects=self._counts["reconnects"],
            stalls=self._counts["stalls"],
            clock_jumps=self._device_clock.jumps,
        )

    async def _configure(self) -> None:
        """The full bring-up: identity, power, setup (a new numbering epoch), data socket, start."""
        name = api.parse_identity((await self._http.get(api.RESOURCE_ROOT)).data)
        if name != api.API_IDENTITY:
            raise DriverError(
                f"the device at {self._http.url} answers as {name!r}, not {api.API_IDENTITY!r}: put the "
                "NIC-500 in SDK mode, or fix gpr_device.host / gpr_device.http_port"
            )
        self.device_info = {"nic": (await self._http.get(api.RESOURCE_NIC_INFO)).data}
        try:
            await self._http.put(api.RESOURCE_POWER, {"state": api.POWER_ALL_ON})
        except api.DeviceRejectedError as exc:
            raise DriverError(f"the NIC could not power the GPR on ({exc}); check the antenna's cable "
                              "and that its transmitter and receiver match") from exc
        gpr_info = (await self._http.get(api.RESOURCE_GPR_INFO)).data
        self.device_info["gpr"] = gpr_info
        reference_ps = api.parse_window_reference_ps(gpr_info)
        if api.parse_state((await self._http.get(api.RESOURCE_ACQUISITION)).data) != api.ACQUISITION_STOP:
            await self._http.put(api.RESOURCE_ACQUISITION, {"state": api.ACQUISITION_STOP})  # setup needs it stopped
        await self._open_data()  # before the setup, so that trace 1 is not missed
        requested = api.setup_from_config(self.cfg, reference_ps)
        try:
            reply = await self._http.put(api.RESOURCE_SETUP, api.setup_payload(requested))
        except api.DeviceRejectedError as exc:
            await self._close_data()
            raise DriverError(
                f"the NIC rejected the acquisition setup (status {exc.status_code}: {exc}); check "
                "gpr_device.points_per_trace (70..30000), time_sampling_interval_ps (50..6400, steps of "
                "50), stacks (a power of 2), window_shift_ns and trigger_period_s (>= 0.00125)"
            ) from exc
        try:
            applied = api.parse_setup(reply.data)
        except ProtocolError:
            applied = api.parse_setup((await self._http.get(api.RESOURCE_SETUP)).data)
        changes = [f"{f.name} {getattr(requested, f.name)} -> {getattr(applied, f.name)}"
                   for f in dataclasses.fields(applied) if getattr(requested, f.name) != getattr(applied, f.name)]
        if changes:
            self._health.error(f"the NIC adjusted the setup: {', '.join(changes)}")
        self.setup = applied
        self._t0_ns = api.first_break_ns(applied, reference_ps)
        self._counter.new_epoch()
        self._new_parser(new_epoch=True)
        await self._http.put(api.RESOURCE_ACQUISITION, {"state": api.ACQUISITION_START})
        self._health.connected = True

    async def _recover(self) -> None:
        """Reconnect: only the data socket if the NIC still acquires, else the full bring-up."""
        state = api.parse_state((await self._http.get(api.RESOURCE_ACQUISITION)).data)
        if state != api.ACQUISITION_START or self.setup is None:
            await self._configure()
            return
        await self._open_data()
        self._new_parser()
        self._health.connected = True

    def _new_parser(self, new_epoch: bool = False) -> None:
        assert self.setup is not None
        self._retire_parser()
        self._parser = TraceStreamParser(self.setup.points_per_trace, self.setup.point_stacks, self._counter)
        self._session += 1
        if self._raw_sink is not None:
            self._raw_sink(GprStreamSetup(self._clock(), self._session, self.setup.points_per_trace,
                                          self.setup.point_stacks, self.setup.dt_ns, self._t0_ns, new_epoch))

    def _retire_parser(self) -> None:
        if self._parser is not None:
            self._counts["resyncs"] += self._parser.resyncs
            self._counts["bytes_skipped"] += self._parser.bytes_skipped
            self._parser = None

    async def _open_data(self) -> None:
        try:
            port = api.parse_data_port((await self._http.get(api.RESOURCE_DATA_SOCKET)).data)
        except (api.DeviceRejectedError, ProtocolError):
            port = self.cfg.data_port  # a NIC that does not report its port: the configured one
        try:
            async with asyncio.timeout(self.cfg.connect_timeout_s):
                self._data = await asyncio.open_connection(self.cfg.host, port)
        except OSError as exc:  # TimeoutError included
            with contextlib.suppress(DriverError):  # the vendor's remedy for a stale data socket
                await self._http.put(api.RESOURCE_DATA_SOCKET_RESET, {})
            raise DriverError(f"cannot open the GPR data socket {self.cfg.host}:{port} ({exc})") from exc

    async def _close_data(self, wait: bool = True) -> None:
        """Close the data socket; the parser's last complete frame is still delivered."""
        if self._parser is not None and self._data is not None:
            await self._handle(self._parser.close(), self._clock(), wait)
        if self._data is not None:
            writer = self._data[1]
            self._data = None
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()
        self._health.connected = False

    async def _run(self) -> None:
        backoff = Backoff(*self._backoff)
        while not self._stopping:  # besides the cancel: a cancel racing a timeout must not keep it alive
            if self._data is None:
                try:
                    await self._recover()
                    self._counts["reconnects"] += 1
                except GprbotError as exc:  # DriverError, or ProtocolError from a malformed reply
                    await self._close_data()
                    self._health.error(f"reconnect failed: {exc}")
                    await self._sleep(backoff.next_s())
                    continue
            delivered_before = self._counts["traces"]
            reason = await self._pump()
            self._health.error(reason)
            await self._close_data()
            if self._counts["traces"] > delivered_before:
                backoff.reset()
            await self._sleep(backoff.next_s())

    async def _pump(self) -> str:
        """Read and deliver until the data socket fails; the reason it did."""
        assert self._data is not None and self._parser is not None
        reader = self._data[0]
        while True:
            try:
                async with asyncio.timeout(self._stall_timeout_s):  # not wait_for: on 3.11 it can swallow a cancel
                    chunk = await reader.read(READ_CHUNK)
            except TimeoutError:
                self._counts["stalls"] += 1
                return f"no data from the NIC for {self._stall_timeout_s:.1f} s (stalled); reconnecting"
            except OSError as exc:
                return f"data socket error ({exc}); reconnecting"
            if not chunk:
                return "the NIC closed the data socket; reconnecting"
            received_s = self._clock()
            if self._raw_sink is not None:
                self._raw_sink(GprRawChunk(received_s, self._session, chunk))
            await self._handle(self._parser.feed(chunk), received_s)

    async def _handle(self, events: list[TraceEvent], received_s: float, wait: bool = True) -> None:
        assert self.setup is not None
        for event in events:
            if isinstance(event, TraceFrame):
                jumps = self._device_clock.jumps
                trace = trace_of(event, self._device_clock, received_s, self.setup.dt_ns, self._t0_ns)
                if self._device_clock.jumps != jumps:
                    self._health.error(f"the NIC's clock jumped by {self._device_clock.last_jump_s:+.3f} s")
                if wait:
                    await self._queue.put(trace)
                else:
                    try:
                        self._queue.put_nowait(trace)
                    except asyncio.QueueFull:
                        self._health.dropped(1)
                        continue
                self._counts["traces"] += 1
                self._health.message(received_s)
            elif isinstance(event, Resync):
                self._health.error(f"corrupt trace stream at byte {event.offset} ({event.reason}); resynchronised")
            elif isinstance(event, TraceGap):
                self._health.dropped(event.missing)
            elif isinstance(event, DuplicateTrace):
                self._health.error(f"trace {event.number} received twice; the copy was discarded")
