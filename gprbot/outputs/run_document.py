"""One run's results as the console's results page (and report.html) show them, read from its directory.

Everything comes from the files the survey wrote (summary.json, pipes.json, rebars.json, the PLY
clouds, the PNGs), so a run pulled to a laptop gives the same page as the robot serves.
"""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import DataFormatError
from gprbot.motion.planner import survey_region
from gprbot.outputs.ply import read_ply
from gprbot.shell import runfiles

_LINE_PICTURE = re.compile(r"(bscan|section)_line(\d+)\.png")


def b64(array: NDArray[Any]) -> str:
    """Little-endian bytes of an array, base64 (what the page turns back into a typed array)."""
    return base64.b64encode(np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<")).tobytes()).decode()


def _json_file(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        return {"error": f"{path.name} is unreadable ({exc})"}


def _cloud(path: Path) -> dict[str, Any] | None:
    """A PLY cloud as base64 float32 xyz (and uint8 rgb when coloured); None if the file is absent."""
    if not path.exists():
        return None
    try:
        points, colours = read_ply(path)
    except DataFormatError as exc:
        return {"error": str(exc), "count": 0}
    record: dict[str, Any] = {"count": len(points), "xyz": b64(points.astype(np.float32))}
    if colours is not None:
        record["rgb"] = b64(colours.astype(np.uint8))
    return record


def surveyed_area(summary: Any) -> list[float] | None:
    """[x0, x1, y0, y1] of the survey lines (from the resolved config in summary.json), if known."""
    try:
        survey = summary["config"]["survey"]
        x0, y0 = (float(v) for v in survey["start_xy_m"])
        lines, spacing = int(survey["lines"]), float(survey["spacing_m"])
        return list(survey_region((x0, y0), float(survey["length_m"]), lines, spacing))
    except (KeyError, TypeError, ValueError):
        return None


def run_document(runs_dir: Path, run: str) -> dict[str, Any]:
    """Everything the results page shows about `run`; CommandError (not_found) if there is no such run."""
    files = runfiles.list_files(runs_dir, run)
    root = runs_dir / run
    summary = _json_file(root / "summary.json")
    lines: dict[int, dict[str, str]] = {}
    for name, _ in files:
        match = _LINE_PICTURE.fullmatch(name)
        if match:
            lines.setdefault(int(match.group(2)), {})[match.group(1)] = name
    return {
        "run": run,
        "summary": summary,
        "pipes": _json_file(root / "pipes.json"),
        "rebars": _json_file(root / "rebars.json"),
        "files": [{"name": name, "size": size} for name, size in files],
        "lines": [{"line": k, **v} for k, v in sorted(lines.items())],
        "map": "map.png" if (root / "map.png").exists() else None,
        "sparse": _cloud(root / "sparse.ply"),
        "dense": _cloud(root / "dense.ply"),
        "area": surveyed_area(summary),
        "complete": summary is not None,
    }
