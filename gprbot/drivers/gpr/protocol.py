"""Sans-IO protocol of the Sensors & Software SPIDAR NIC-500 in "SDK mode" (no I/O, no clock).

Two halves:
* the data socket: a byte stream of traces, each a little-endian header `<LLLLHH` (tv_sec, tv_nsec,
  trace number, status, stacks, header size) followed by float32 samples in mV. `TraceStreamParser`
  frames it, checks every frame for plausibility and resynchronises on garbage;
* the control API: HTTP/1.1 GET/PUT on port 8080, PUT bodies form-encoded as `data=<json>`, replies
  `{"data": ..., "status": {"status_code", "message", "type"}, "success": bool}`.

This module gathers the protocol's public names. They live in `trace_stream` (the data socket),
`sdk_http` (HTTP/1.1 framing) and `sdk_api` (the JSON API and the acquisition setup).
"""

from __future__ import annotations

from gprbot.drivers.gpr.sdk_api import (
    ACQUISITION_START,
    ACQUISITION_STOP,
    API_IDENTITY,
    DEFAULT_WINDOW_SHIFT_REFERENCE_PS,
    POWER_ALL_ON,
    POWER_NIC_ONLY,
    RESOURCE_ACQUISITION,
    RESOURCE_DATA_SOCKET,
    RESOURCE_DATA_SOCKET_RESET,
    RESOURCE_GPR_INFO,
    RESOURCE_NIC_INFO,
    RESOURCE_POWER,
    RESOURCE_ROOT,
    RESOURCE_SETUP,
    RESOURCE_STATUS,
    WARNING_CODES,
    AcquisitionSetup,
    ApiReply,
    DeviceRejectedError,
    api_form,
    first_break_ns,
    parse_api_reply,
    parse_data_port,
    parse_identity,
    parse_setup,
    parse_state,
    parse_window_reference_ps,
    setup_from_config,
    setup_payload,
)
from gprbot.drivers.gpr.sdk_http import (
    MAX_BODY_BYTES,
    MAX_HEAD_BYTES,
    HttpResponse,
    HttpResponseParser,
    build_request,
)
from gprbot.drivers.gpr.trace_stream import (
    HEADER,
    HEADER_SIZE,
    MAX_ABS_SAMPLE_MV,
    MAX_HEADER_SIZE,
    MAX_STATUS,
    NS_PER_S,
    VALID_STACKS,
    DuplicateTrace,
    Resync,
    TraceCounter,
    TraceEvent,
    TraceFrame,
    TraceGap,
    TraceStreamParser,
    encode_frame,
)

__all__ = [
    "ACQUISITION_START", "ACQUISITION_STOP", "API_IDENTITY", "DEFAULT_WINDOW_SHIFT_REFERENCE_PS", "HEADER",
    "HEADER_SIZE", "MAX_ABS_SAMPLE_MV", "MAX_BODY_BYTES", "MAX_HEADER_SIZE", "MAX_HEAD_BYTES", "MAX_STATUS",
    "NS_PER_S", "POWER_ALL_ON", "POWER_NIC_ONLY", "RESOURCE_ACQUISITION", "RESOURCE_DATA_SOCKET",
    "RESOURCE_DATA_SOCKET_RESET", "RESOURCE_GPR_INFO", "RESOURCE_NIC_INFO", "RESOURCE_POWER", "RESOURCE_ROOT",
    "RESOURCE_SETUP", "RESOURCE_STATUS", "VALID_STACKS", "WARNING_CODES", "AcquisitionSetup", "ApiReply",
    "DeviceRejectedError", "DuplicateTrace", "HttpResponse", "HttpResponseParser", "Resync", "TraceCounter",
    "TraceEvent", "TraceFrame", "TraceGap", "TraceStreamParser", "api_form", "build_request", "encode_frame",
    "first_break_ns", "parse_api_reply", "parse_data_port", "parse_identity", "parse_setup", "parse_state",
    "parse_window_reference_ps", "setup_from_config", "setup_payload",
]
