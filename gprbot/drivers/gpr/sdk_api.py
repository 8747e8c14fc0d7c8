"""Sans-IO JSON API of the SPIDAR NIC-500 in SDK mode: resources, reply envelopes, the acquisition setup.

Requests are HTTP/1.1 GET/PUT on port 8080, PUT bodies form-encoded as `data=<json>`, replies
`{"data": ..., "status": {"status_code", "message", "type"}, "success": bool}`.

Source: the vendor's public SDK docs and examples (github.com/SensoftInc/spidar-sdk: nic_setup,
nic_power, nic_acquisition). Where they are silent, the choice is a constant here.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from gprbot.config import GprDeviceConfig
from gprbot.drivers.gpr.sdk_http import HttpResponse
from gprbot.errors import DriverError, ProtocolError

API_IDENTITY = "NIC-500 SDK"  # data.name of GET /api in SDK mode (vendor examples)
RESOURCE_ROOT = "/api"
RESOURCE_NIC_INFO = "/api/nic/system_information"
RESOURCE_GPR_INFO = "/api/nic/gpr/system_information"
RESOURCE_DATA_SOCKET = "/api/nic/gpr/data_socket"
RESOURCE_DATA_SOCKET_RESET = "/api/nic/gpr/data_socket_reset"
RESOURCE_POWER = "/api/nic/power"
RESOURCE_SETUP = "/api/nic/setup"
RESOURCE_ACQUISITION = "/api/nic/acquisition"
RESOURCE_STATUS = "/api/nic/status"
POWER_NIC_ONLY = 1  # 0 would switch the NIC off too: it could then only be restarted by hand
POWER_ALL_ON = 2
ACQUISITION_STOP = 0  # also resets the trace numbering
ACQUISITION_START = 1
WARNING_CODES = range(900, 1000)  # e.g. 913 "Modified Input": applied after rounding
# Units without a calibrated window_time_shift_reference_ps (pulseEKKO PRO): the vendor's default.
DEFAULT_WINDOW_SHIFT_REFERENCE_PS = -55000.0


class DeviceRejectedError(DriverError):
    """The NIC answered a request with an error status (its status code and message kept)."""

    def __init__(self, resource: str, status_code: int, message: str, http_status: int):
        super().__init__(f"the NIC rejected {resource}: status {status_code} ({message}, HTTP {http_status})")
        self.resource = resource
        self.status_code = status_code
        self.http_status = http_status


@dataclass(frozen=True)
class ApiReply:
    """A successful reply: its data and status (0, or a 9xx warning)."""

    data: Any
    status_code: int
    message: str


def api_form(payload: Mapping[str, Any]) -> dict[str, str]:
    """The PUT body of the API: the JSON payload in the form field `data`."""
    return {"data": json.dumps(payload)}


def parse_api_reply(response: HttpResponse, resource: str) -> ApiReply:
    """Decode the JSON envelope; ProtocolError if it is not one, DeviceRejectedError on an error status."""
    try:
        doc = json.loads(response.body)
    except ValueError as exc:
        raise ProtocolError(f"{resource}: the reply (HTTP {response.status}) is not JSON ({exc})") from exc
    if not isinstance(doc, dict):
        raise ProtocolError(f"{resource}: the reply is JSON but not an object")
    status = doc.get("status")
    code, message, kind = 0, str(doc.get("message", "")), ""
    if isinstance(status, dict):
        raw_code = status.get("status_code", 0)
        if not isinstance(raw_code, int) or isinstance(raw_code, bool):
            raise ProtocolError(f"{resource}: status_code is {raw_code!r}, not an integer")
        code, message, kind = raw_code, str(status.get("message", message)), str(status.get("type", ""))
    failed = (response.status >= 400 or doc.get("success") is False or kind in ("ERROR", "FATAL")
              or (code != 0 and code not in WARNING_CODES))
    if failed:
        raise DeviceRejectedError(resource, code, message or response.reason, response.status)
    return ApiReply(doc.get("data"), code, message)


def _field(data: Any, *path: str) -> Any:
    for key in path:
        if not isinstance(data, dict) or key not in data:
            raise ProtocolError(f"the NIC's reply lacks {'.'.join(path)}")
        data = data[key]
    return data


def parse_identity(data: Any) -> str | None:
    """The API's name (GET /api), or None when the reply has none."""
    name = data.get("name") if isinstance(data, dict) else None
    return name if isinstance(name, str) else None


def parse_state(data: Any) -> int:
    """The `state` of a power or acquisition reply."""
    state = _field(data, "state")
    if not isinstance(state, int):
        raise ProtocolError(f"state is {state!r}, not an integer")
    return state


def parse_data_port(data: Any) -> int:
    """The data socket's TCP port (GET api/nic/gpr/data_socket)."""
    port = _field(data, "data_socket", "port")
    if not isinstance(port, int) or not 0 < port < 65536:
        raise ProtocolError(f"data socket port is {port!r}")
    return port


def parse_window_reference_ps(data: Any) -> float | None:
    """The calibrated window shift placing the first break at point 1, None if the unit has none."""
    gpr = _field(data, "gpr")
    value = gpr.get("window_time_shift_reference_ps") if isinstance(gpr, dict) else None
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        raise ProtocolError(f"window_time_shift_reference_ps is {value!r}") from None


@dataclass(frozen=True)
class AcquisitionSetup:
    """The NIC's acquisition parameters (api/nic/setup), as requested or as applied."""

    points_per_trace: int
    time_sampling_interval_ps: float
    point_stacks: int
    window_time_shift_ps: float
    period_s: float
    trigger_mode: str = "Free"

    @property
    def dt_ns(self) -> float:
        """Sample interval in ns."""
        return self.time_sampling_interval_ps / 1000.0


def _json_number(x: float) -> int | float:
    return int(x) if float(x).is_integer() else x  # the API documents integers for ps values


def setup_from_config(cfg: GprDeviceConfig, reference_ps: float | None) -> AcquisitionSetup:
    """The setup to send: `window_shift_ns` is relative to the unit's calibrated reference.

    The reference places the first break at point 1; shifting the window by -1 ns puts it 1 ns into
    the trace (the vendor's examples do the same with a number of points).
    """
    reference = DEFAULT_WINDOW_SHIFT_REFERENCE_PS if reference_ps is None else reference_ps
    return AcquisitionSetup(
        points_per_trace=cfg.points_per_trace,
        time_sampling_interval_ps=cfg.time_sampling_interval_ps,
        point_stacks=cfg.stacks,
        window_time_shift_ps=5 * round((reference + cfg.window_shift_ns * 1000.0) / 5),  # 5 ps steps
        period_s=cfg.trigger_period_s,
    )


def first_break_ns(setup: AcquisitionSetup, reference_ps: float | None) -> float:
    """Where the first break (time zero) lies in each trace, in ns after sample 0."""
    reference = DEFAULT_WINDOW_SHIFT_REFERENCE_PS if reference_ps is None else reference_ps
    return (reference - setup.window_time_shift_ps) / 1000.0


def setup_payload(setup: AcquisitionSetup) -> dict[str, Any]:
    """The JSON of PUT api/nic/setup."""
    return {
        "gpr0": {"parameters": {
            "points_per_trace": setup.points_per_trace,
            "time_sampling_interval_ps": _json_number(setup.time_sampling_interval_ps),
            "point_stacks": setup.point_stacks,
            "window_time_shift_ps": _json_number(setup.window_time_shift_ps),
            "trigger_mode": setup.trigger_mode,
        }},
        "timer": {"parameters": {"period_s": setup.period_s}},
    }


def parse_setup(data: Any) -> AcquisitionSetup:
    """The setup in a reply of api/nic/setup (the docs show the GPR both as "gpr0" and "gpr")."""
    gpr_key = "gpr0" if isinstance(data, dict) and "gpr0" in data else "gpr"
    gpr = _field(data, gpr_key, "parameters")
    timer = _field(data, "timer", "parameters")
    try:
        return AcquisitionSetup(
            points_per_trace=int(gpr["points_per_trace"]),
            time_sampling_interval_ps=float(gpr["time_sampling_interval_ps"]),
            point_stacks=int(gpr["point_stacks"]),
            window_time_shift_ps=float(gpr["window_time_shift_ps"]),
            period_s=float(timer["period_s"]),
            trigger_mode=str(gpr.get("trigger_mode", "Free")),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ProtocolError(f"the NIC's setup reply is incomplete or malformed ({exc!r})") from exc
