"""Result files that survive a crash (written through gprbot.atomic_files): JSON and pipes.json."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.atomic_files import write_bytes_atomic
from gprbot.errors import DataFormatError
from gprbot.geometry import polyline_length
from gprbot.reconstruct.completion import PipeModel, Reconstruction, pipe_colors

PIPES_FORMAT = "gprbot-pipes"
PIPES_VERSION = 1
SITE_FRAME = "site: x forward along the survey lines, y left, z up (REP-103); ground surface at z = 0"
_DECIMALS = 6  # µm: far below any measurement, keeps the file readable


def _json_default(value: Any) -> Any:
    """JSON for numpy scalars and arrays and paths; anything else is a bug in the caller."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


_INLINE_WIDTH = 100


def _nested(value: Any) -> bool:
    return isinstance(value, dict | list | tuple | np.ndarray)


def _inline(value: Any) -> bool:
    """Written on one line: lists of numbers or of points (polylines), and short flat mappings."""
    if isinstance(value, list | tuple):
        return all(not _nested(v) or (isinstance(v, list | tuple) and not any(map(_nested, v))) for v in value)
    if isinstance(value, dict):
        return not any(map(_nested, value.values())) and len(json.dumps(value, default=_json_default)) <= _INLINE_WIDTH
    return True


def json_text(obj: Any, indent: str = "") -> str:
    """Indented JSON in which points, polylines and short flat mappings stay on one line each."""
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    inner = indent + "  "
    if isinstance(obj, dict) and not _inline(obj):
        body = ",\n".join(f"{inner}{json.dumps(str(k))}: {json_text(v, inner)}" for k, v in obj.items())
        return "{\n" + body + "\n" + indent + "}"
    if isinstance(obj, list | tuple) and not _inline(obj):
        return "[\n" + ",\n".join(inner + json_text(v, inner) for v in obj) + "\n" + indent + "]"
    return json.dumps(obj, allow_nan=False, default=_json_default, separators=(", ", ": "))


def write_json_atomic(path: str | os.PathLike[str], obj: Any) -> None:
    """Write obj as indented JSON (numpy values allowed, NaN refused) atomically."""
    write_bytes_atomic(path, (json_text(obj) + "\n").encode("utf-8"))


def _rounded(values: Any) -> Any:
    return np.round(np.asarray(values, dtype=np.float64), _DECIMALS).tolist()


def pipes_document(reconstruction: Reconstruction, meta: Mapping[str, Any]) -> dict[str, Any]:
    """The content of pipes.json: meta (units, frame, run id, ...) and one record per pipe."""
    colours = pipe_colors(len(reconstruction.pipes))
    pipes = []
    for index, pipe in enumerate(reconstruction.pipes):
        pipes.append(
            {
                "id": index,
                "axis_m": _rounded(pipe.axis),
                "endpoints_m": _rounded(pipe.axis[[0, -1]]),
                "length_m": round(polyline_length(pipe.axis), _DECIMALS),
                "depth_of_cover_m": round(pipe.depth_of_cover_m, _DECIMALS),
                "diameter_m": round(pipe.diameter_m, _DECIMALS),
                "confidence": round(pipe.confidence, 4),
                "pose_std_m": round(pipe.pose_std_m, _DECIMALS),
                "n_slices": pipe.n_slices,
                "ends_on": {"start": pipe.ends_on[0], "end": pipe.ends_on[1]},
                # how much of the axis at each end no line saw (the refined completion continued it there)
                "inferred_m": {"start": round(pipe.inferred_m[0], _DECIMALS),
                               "end": round(pipe.inferred_m[1], _DECIMALS)},
                "colour": "#{:02x}{:02x}{:02x}".format(*(int(c) for c in colours[index])),
            }
        )
    header = {"frame": SITE_FRAME, **meta, "units": "m"}
    return {"format": PIPES_FORMAT, "version": PIPES_VERSION, "meta": header, "pipes": pipes}


def write_pipes_json(path: str | os.PathLike[str], reconstruction: Reconstruction, meta: dict[str, Any]) -> None:
    """Write pipes.json: per pipe its axis (m, site frame), depth of cover, diameter, confidence, slices."""
    write_json_atomic(path, pipes_document(reconstruction, meta))


def _inferred(record: Mapping[str, Any]) -> tuple[float, float]:
    """The inferred lengths of a pipe record (absent in files from before they were written: none)."""
    return float(record.get("start", 0.0)), float(record.get("end", 0.0))


def read_pipes_json(path: str | os.PathLike[str]) -> list[PipeModel]:
    """The pipes of a pipes.json (ours, e.g. pulled from a robot) as PipeModels; DataFormatError if malformed."""
    try:
        document = json.loads(Path(path).read_text())
        if document.get("format") != PIPES_FORMAT:
            raise DataFormatError(f"{path}: not a gprbot pipes file (format {document.get('format')!r})")
        return [
            PipeModel(
                axis=np.asarray(p["axis_m"], dtype=np.float64).reshape(-1, 3),
                radius_m=float(p["diameter_m"]) / 2,
                depth_of_cover_m=float(p["depth_of_cover_m"]),
                diameter_m=float(p["diameter_m"]),
                confidence=float(p["confidence"]),
                n_slices=int(p["n_slices"]),
                ends_on=(p["ends_on"]["start"], p["ends_on"]["end"]),
                pose_std_m=float(p.get("pose_std_m", 0.0)),  # absent in files from before it was written
                inferred_m=_inferred(p.get("inferred_m", {})),
            )
            for p in document["pipes"]
        ]
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise DataFormatError(f"{path}: unreadable pipes file ({exc}); pull it again") from exc
