"""The HTTP side of the NIC-500 emulator: the SDK-mode JSON API over the emulator's state.

It follows the vendor's documented behaviour (resources, status codes, parameter ranges and
resolutions of api/nic/setup, numbering from 1 after each setup). Where the docs are silent, errors are
answered with HTTP 400 (404 for an unknown resource) as well as their status code.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qs

from gprbot.drivers.gpr import sdk_api as api
from gprbot.drivers.gpr.sdk_api import AcquisitionSetup, setup_payload
from gprbot.drivers.gpr.trace_stream import VALID_STACKS

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


class EmulatedSdkApi:
    """The emulated NIC's HTTP handlers, mixed into `GprSdkEmulator`, which holds the state they act on."""

    identity: str
    window_shift_reference_ps: float | None
    enforce_device_ranges: bool
    power_state: int
    acquisition_state: int
    setup: AcquisitionSetup | None
    last_number: int
    requests: list[tuple[str, str]]
    _rejections: list[tuple[int, int]]
    _wake: asyncio.Event

    @property
    def data_port(self) -> int:
        """The bound data socket port."""
        raise NotImplementedError

    def _drop_client(self) -> None:
        raise NotImplementedError

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
                api.RESOURCE_ROOT: lambda: _envelope(resource, {"name": self.identity, "version": "emulated"}),
                api.RESOURCE_NIC_INFO: lambda: _envelope(resource, {"nic_serial_number": "EMULATED",
                                                                    "app_version": "sim"}),
                api.RESOURCE_GPR_INFO: self._gpr_info,
                api.RESOURCE_POWER: lambda: _envelope(resource, {"state": self.power_state}),
                api.RESOURCE_SETUP: lambda: _envelope(resource, self._setup_data()),
                api.RESOURCE_ACQUISITION: lambda: _envelope(resource, {"state": self.acquisition_state}),
                api.RESOURCE_STATUS: lambda: _envelope(resource, {"processor": {"temperature_c": 40.0},
                                                                  "power": {"input_voltage": 12.0}}),
                api.RESOURCE_DATA_SOCKET: lambda: _envelope(resource, {"data_socket": {"port": self.data_port}}),
            }
            if resource in getters:
                return getters[resource]()
        elif method == "PUT" and resource in (api.RESOURCE_POWER, api.RESOURCE_SETUP, api.RESOURCE_ACQUISITION,
                                              api.RESOURCE_DATA_SOCKET_RESET):
            try:
                fields = parse_qs(body.decode("utf-8"), keep_blank_values=True)
                payload = json.loads(fields["data"][0]) if "data" in fields else {}
            except (ValueError, KeyError):
                return _envelope(resource, None, BAD_FORMAT, "Invalid Input Parameter Format")
            if not isinstance(payload, dict):
                return _envelope(resource, None, BAD_FORMAT, "Invalid Input Parameter Format")
            if resource == api.RESOURCE_POWER:
                return self._put_power(payload)
            if resource == api.RESOURCE_SETUP:
                return self._put_setup(payload)
            if resource == api.RESOURCE_ACQUISITION:
                return self._put_acquisition(payload)
            self._drop_client()
            return _envelope(resource, {})
        return _envelope(resource, None, NOT_SUPPORTED, "The requested command is not supported")

    def _gpr_info(self) -> Reply:
        if self.power_state != api.POWER_ALL_ON:
            return _envelope(api.RESOURCE_GPR_INFO, None, NOT_POWERED, "GPR Not Powered")
        gpr = {"unit_serial_number": "EMULATED", "app_code_version": "sim",
               "window_time_shift_reference_ps": self.window_shift_reference_ps}
        return _envelope(api.RESOURCE_GPR_INFO, {"gpr": gpr})

    def _setup_data(self) -> dict[str, Any]:
        return setup_payload(self.setup) if self.setup is not None else {}

    def _put_power(self, payload: dict[str, Any]) -> Reply:
        state = payload.get("state")
        if state not in (0, 1, 2):
            return _envelope(api.RESOURCE_POWER, None, OUT_OF_RANGE, "Value Out Of Range")
        self.power_state = int(state)  # 0 (NIC off) is accepted but not modelled beyond the state
        return _envelope(api.RESOURCE_POWER, {"state": self.power_state})

    def _put_setup(self, payload: dict[str, Any]) -> Reply:
        if self._rejections:
            code, http = self._rejections.pop(0)
            return http, _envelope(api.RESOURCE_SETUP, None, code, "Setup rejected (injected fault)")[1]
        if self.power_state != api.POWER_ALL_ON:
            return _envelope(api.RESOURCE_SETUP, None, NOT_POWERED, "GPR Not Powered")
        if self.acquisition_state != api.ACQUISITION_STOP:
            return _envelope(api.RESOURCE_SETUP, None, ALREADY_RUNNING, "GPR Already Running")
        gpr = payload.get("gpr0", payload.get("gpr", {}))
        timer = payload.get("timer", {})
        if not isinstance(gpr, dict) or not isinstance(timer, dict) or not gpr.keys() <= {"parameters"} \
                or not timer.keys() <= {"parameters"}:
            return _envelope(api.RESOURCE_SETUP, None, BAD_FORMAT, "Invalid Input Parameter Format")
        current = setup_payload(self.setup or AcquisitionSetup(100, 100.0, 1, -48000.0, 1.0))
        merged = {**current["gpr0"]["parameters"], **gpr.get("parameters", {})}
        period = {**current["timer"]["parameters"], **timer.get("parameters", {})}["period_s"]
        try:
            requested = AcquisitionSetup(int(merged["points_per_trace"]), float(merged["time_sampling_interval_ps"]),
                                         int(merged["point_stacks"]), float(merged["window_time_shift_ps"]),
                                         float(period), str(merged["trigger_mode"]))
        except (TypeError, ValueError):
            return _envelope(api.RESOURCE_SETUP, None, BAD_FORMAT, "Invalid Input Parameter Format")
        applied, code, message = check_setup(requested, self.enforce_device_ranges)
        if code == OUT_OF_RANGE:
            return _envelope(api.RESOURCE_SETUP, None, code, message)
        self.setup, self.last_number = applied, 0  # a setup resets the numbering to 1
        if code:
            return _envelope(api.RESOURCE_SETUP, self._setup_data(), code, message)
        return _envelope(api.RESOURCE_SETUP, self._setup_data())

    def _put_acquisition(self, payload: dict[str, Any]) -> Reply:
        state = payload.get("state")
        if state not in (0, 1, 2):
            return _envelope(api.RESOURCE_ACQUISITION, None, BAD_FORMAT, "Invalid Parameter Format")
        if self.power_state != api.POWER_ALL_ON:
            return _envelope(api.RESOURCE_ACQUISITION, None, NOT_POWERED, "GPR Not Powered")
        running = self.acquisition_state == api.ACQUISITION_START
        if state == api.ACQUISITION_START and running:
            return _envelope(api.RESOURCE_ACQUISITION, None, ALREADY_RUNNING, "GPR Already Running")
        if state == api.ACQUISITION_START and self.setup is None:
            return _envelope(api.RESOURCE_ACQUISITION, None, NOT_INITIALISED, "GPR Not Initialized")
        if state != api.ACQUISITION_START and not running:
            return _envelope(api.RESOURCE_ACQUISITION, None, NOT_RUNNING, "GPR Not Running")
        self.acquisition_state = int(state)
        if state == api.ACQUISITION_STOP:
            self.last_number = 0
        self._wake.set()
        return _envelope(api.RESOURCE_ACQUISITION, {"state": self.acquisition_state})
