"""`gprbot export-mcap RUN`: the run log as an MCAP file (JSON messages) that Foxglove and similar tools open.

Topics: /pose (foxglove.PoseInFrame, frame "site"), /gpr/trace, /imu, /wheels, /survey/events, and
/camera/color + /camera/depth (foxglove.RawImage) for recorded RGB-D frames; any other logged type gets
a topic named after it. Log times are the receive times on the robot's monotonic clock, shifted so that
the first record falls at the run's creation wall time (the header's `created`), so tools show a date.
The run's header goes into the file as metadata "gprbot.header".
"""

from __future__ import annotations

import base64
import dataclasses
import json
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import Writer

from gprbot.atomic_files import atomic_open
from gprbot.errors import DataFormatError
from gprbot.runlog_reader import LogRecord, RunLogReader, UndecodedMessage

_ANY_OBJECT = {"type": "object"}
POSE_SCHEMA = {
    "title": "foxglove.PoseInFrame", "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {
            "position": {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}},
            "orientation": {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}}},
    },
}
RAW_IMAGE_SCHEMA = {
    "title": "foxglove.RawImage", "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"}, "width": {"type": "integer"}, "height": {"type": "integer"},
        "encoding": {"type": "string"}, "step": {"type": "integer"},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}


@dataclass(frozen=True)
class McapExport:
    """What an export wrote: the file, messages per topic, and the log's state (torn, ended)."""

    path: Path
    messages: dict[str, int]
    log_status: dict[str, Any]


def _stamp(t: float) -> dict[str, int]:
    ns = round(t * 1e9)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def plain(value: Any) -> Any:
    """A logged value as JSON data: dataclasses as objects, arrays as lists, bytes as base64."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):  # JSON has no NaN: null instead
            return [plain(v) for v in value] if value.ndim > 1 else [float(v) if np.isfinite(v) else None
                                                                      for v in value]
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value


def _pose(message: Any) -> list[tuple[str, dict[str, Any]]]:
    p, q = np.asarray(message.position, np.float64), np.asarray(message.orientation, np.float64)
    return [("/pose", {"timestamp": _stamp(message.t), "frame_id": "site", "pose": {
        "position": dict(zip("xyz", map(float, p), strict=True)),
        "orientation": dict(zip("xyzw", map(float, q), strict=True))}})]


def _rgbd(message: Any) -> list[tuple[str, dict[str, Any]]]:
    color, depth = np.ascontiguousarray(message.color), np.ascontiguousarray(message.depth, dtype="<u2")
    h, w = color.shape[:2]
    base = {"timestamp": _stamp(message.t), "frame_id": "camera_color_optical_frame", "width": w, "height": h}
    return [
        ("/camera/color", base | {"encoding": "bgr8", "step": w * 3, "data": plain(color.tobytes())}),
        ("/camera/depth", base | {"encoding": "16UC1", "step": w * 2, "data": plain(depth.tobytes())}),
    ]


_TOPICS = {"Trace": "/gpr/trace", "ImuSample": "/imu", "WheelSpeeds": "/wheels", "SurveyEvent": "/survey/events",
           "WheelEncoders": "/wheels/encoders", "VoMeasurement": "/vo"}
_SPECIAL: dict[str, tuple[Callable[[Any], list[tuple[str, dict[str, Any]]]], dict[str, Any]]] = {
    "Pose": (_pose, POSE_SCHEMA), "RawRgbdFrame": (_rgbd, RAW_IMAGE_SCHEMA),
}


def messages_of(record: LogRecord) -> tuple[str, list[tuple[str, dict[str, Any]]]]:
    """(schema name, [(topic, JSON object)]) for one log record."""
    message = record.message
    if isinstance(message, UndecodedMessage):
        return "gprbot.Undecoded", [(f"/undecoded/{message.type_name}", {
            "type_name": message.type_name, "payload": plain(message.payload)})]
    name = type(message).__name__
    if name in _SPECIAL:
        convert, schema = _SPECIAL[name]
        return str(schema["title"]), convert(message)
    return f"gprbot.{name}", [(_TOPICS.get(name, f"/{name}"), plain(message))]


def _schema_for(name: str) -> dict[str, Any]:
    for _, schema in _SPECIAL.values():
        if schema["title"] == name:
            return schema
    return {"title": name, **_ANY_OBJECT}


def export_mcap(run_dir: str | os.PathLike[str], out_path: str | os.PathLike[str] | None = None,
                on_record: Callable[[], None] | None = None) -> McapExport:
    """Write RUN/run.mcap (or out_path) from the run's log; a torn log exports what is readable before the tear."""
    run = Path(run_dir)
    reader = RunLogReader(run)
    target = Path(out_path) if out_path is not None else run / "run.mcap"
    counts: dict[str, int] = {}
    try:
        with atomic_open(target) as handle:
            writer = Writer(handle)
            writer.start(profile="", library="gprbot")
            writer.add_metadata("gprbot.header", {"json": json.dumps(plain(reader.header))})
            _write_records(writer, reader, counts, on_record)
            writer.finish()  # type: ignore[no-untyped-call]
    except OSError as exc:
        raise DataFormatError(f"cannot write {target}: {exc}; give a writable --out") from exc
    return McapExport(target, counts, reader.status())


def _write_records(writer: Writer, records: Iterable[LogRecord] | RunLogReader, counts: dict[str, int],
                   on_record: Callable[[], None] | None) -> None:
    header = records.header if isinstance(records, RunLogReader) else {}
    created = float(header.get("created") or 0.0)
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}
    offset_s: float | None = None
    for record in records:
        if offset_s is None:
            offset_s = created - record.t_received if created > 0 else 0.0
        log_time = max(0, round((record.t_received + offset_s) * 1e9))
        schema_name, items = messages_of(record)
        if schema_name not in schemas:
            schemas[schema_name] = writer.register_schema(schema_name, "jsonschema",
                                                          json.dumps(_schema_for(schema_name)).encode())
        for topic, obj in items:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "json", schemas[schema_name])
            data = json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()
            writer.add_message(channels[topic], log_time=log_time, data=data, publish_time=log_time,
                               sequence=counts.get(topic, 0))
            counts[topic] = counts.get(topic, 0) + 1
        if on_record is not None:
            on_record()
