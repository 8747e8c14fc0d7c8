"""The NIC-500's control channel and clock, as the driver uses them: an asyncio HTTP client of the SDK
API with errors that say what to check, and the conversion of the NIC's timestamps to host time."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping
from typing import Any

from gprbot.drivers.gpr.sdk_api import ApiReply, api_form, parse_api_reply
from gprbot.drivers.gpr.sdk_http import HttpResponse, HttpResponseParser, build_request
from gprbot.errors import DriverError, ProtocolError

READ_CHUNK = 64 * 1024


class SdkHttpClient:
    """A minimal HTTP/1.1 client of the SDK API: one connection per request, a timeout on each."""

    def __init__(self, host: str, port: int, timeout_s: float):
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self.url = f"http://{host}:{port}"

    async def get(self, resource: str) -> ApiReply:
        """GET a resource."""
        return await self._request("GET", resource, None)

    async def put(self, resource: str, payload: Mapping[str, Any]) -> ApiReply:
        """PUT a JSON payload to a resource."""
        return await self._request("PUT", resource, api_form(payload))

    async def _request(self, method: str, resource: str, form: dict[str, str] | None) -> ApiReply:
        request = build_request(method, self.host, self.port, resource, form)
        try:
            async with asyncio.timeout(self.timeout_s):
                response = await self._exchange(request)
            return parse_api_reply(response, resource)
        except TimeoutError as exc:  # before OSError: TimeoutError is one
            raise DriverError(
                f"the GPR at {self.url} did not answer {method} {resource} within {self.timeout_s} s; "
                "check that the NIC-500 is powered and cabled (gpr_device.connect_timeout_s)"
            ) from exc
        except OSError as exc:
            raise DriverError(
                f"no GPR answers at {self.url} ({exc.strerror or exc}); check that the NIC-500 is powered, "
                "cabled and at gpr_device.host / gpr_device.http_port"
            ) from exc
        except ProtocolError as exc:
            raise DriverError(
                f"something that is not a NIC-500 in SDK mode answers at {self.url}: {exc}; "
                "check gpr_device.host / gpr_device.http_port"
            ) from exc

    async def _exchange(self, request: bytes) -> HttpResponse:
        reader, writer = await asyncio.open_connection(self.host, self.port)
        try:
            writer.write(request)
            await writer.drain()
            parser = HttpResponseParser()
            while True:
                chunk = await reader.read(READ_CHUNK)
                if not chunk:
                    return parser.close()
                response = parser.feed(chunk)
                if response is not None:
                    return response
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()


class NicClock:
    """Converts the NIC's timestamps (its real-time clock) to host monotonic time, with jump detection.

    Not the RealSense's DeviceClock on purpose: the NIC stamps one stream with a wall clock that NTP may
    set, so a latency bound catches its jumps and times never go backwards; the D435i's four streams
    share a free-running clock, tracked with a windowed minimum per stream.

    Host receive time minus device time is the clock offset plus a latency >= 0, so the smallest such
    sample is the best offset estimate; it may creep up by `drift_per_s` per host second to follow clock
    drift. A device time going backwards or an apparent latency above `max_latency_s` means the NIC's
    clock was set (NTP, RTC, reboot): the estimate is re-anchored and the jump counted. Times never
    decrease: while the estimate improves, a trace may be given its predecessor's time.
    """

    def __init__(self, max_latency_s: float = 2.0, drift_per_s: float = 1e-4):
        self.max_latency_s = max_latency_s
        self.drift_per_s = drift_per_s
        self.jumps = 0
        self.last_jump_s = 0.0
        self._offset: float | None = None
        self._last_device = 0.0
        self._last_received = 0.0
        self._last_t = -float("inf")

    def to_host(self, device_s: float, received_s: float) -> float:
        """Host time of the trace stamped `device_s` and received at host time `received_s`."""
        sample = received_s - device_s
        if self._offset is None:
            self._offset = sample
        else:
            allowed = self._offset + self.drift_per_s * max(0.0, received_s - self._last_received)
            if device_s < self._last_device or sample > allowed + self.max_latency_s:
                self._jump(sample)
            else:
                if sample < allowed - self.max_latency_s:
                    self._jump(sample)
                self._offset = min(allowed, sample)
        self._last_device, self._last_received = device_s, received_s
        # Never before the previous trace: a better offset estimate must not reorder traces.
        self._last_t = max(device_s + self._offset, self._last_t)
        return self._last_t

    def _jump(self, sample: float) -> None:
        assert self._offset is not None
        self.jumps += 1
        self.last_jump_s = self._offset - sample  # how far the device clock moved beyond elapsed time
        self._offset = sample
