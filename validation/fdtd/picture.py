"""A B-scan picture with the truth drawn on it: `python -m validation.fdtd.picture NAME [OUT.png]`.

Overlays, each plus the source peak delay: red/orange, the first-arrival time to each pipe's/rebar's surface
(refraction at the concrete surface, Fermat on a sampled surface; on the flanks this is a grazing path that
carries little energy); blue, straight rays in concrete to the top point plus the vertical air gap.
Uses only numpy and OpenCV (the project venv has both).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.dzt import read_dzt
from validation.fdtd.convert import DATA, WORK

C = 0.299792458
FloatArray = NDArray[np.float64]


def _leg(ax: FloatArray, h: float, px: FloatArray, pz: FloatArray, v: float) -> FloatArray:
    """Refracted one-way time (ns) from antennas at x = ax (height h) to points (px, pz below the surface)."""
    xs = np.linspace(min(ax.min(), px.min()) - 0.05, max(ax.max(), px.max()) + 0.05, 600)
    air = np.sqrt((xs[None, :] - ax[:, None]) ** 2 + h * h) / C  # (antennas, crossings)
    ground = np.sqrt((px[:, None] - xs[None, :]) ** 2 + pz[:, None] ** 2) / v  # (points, crossings)
    return np.asarray((air[:, None, :] + ground[None, :, :]).min(axis=2))  # (antennas, points)


def arrival_ns(record: dict[str, Any], x_m: float, depth_m: float, radius_m: float) -> NDArray[np.float64]:
    """Earliest two-way time (ns after the source peak) to a circle's surface, for every trace."""
    mid = np.asarray(record["trace_x_m"])
    h, off, v = record["antenna"]["height_m"], record["antenna"]["tx_rx_offset_m"], record["velocity_m_per_ns"]
    angle = np.linspace(0.05, np.pi - 0.05, 90)
    px, pz = x_m + radius_m * np.cos(angle), depth_m - radius_m * np.sin(angle)
    return np.asarray((_leg(mid - off / 2, h, px, pz, v) + _leg(mid + off / 2, h, px, pz, v)).min(axis=1))


def straight_ns(record: dict[str, Any], x_m: float, depth_m: float, radius_m: float) -> NDArray[np.float64]:
    """Two-way time with straight rays in concrete (antennas on the surface) plus the vertical air gap."""
    mid = np.asarray(record["trace_x_m"])
    h, off, v = record["antenna"]["height_m"], record["antenna"]["tx_rx_offset_m"], record["velocity_m_per_ns"]
    top = depth_m - radius_m
    legs = np.hypot(mid - off / 2 - x_m, top) + np.hypot(mid + off / 2 - x_m, top)
    return np.asarray(2.0 * h / C + legs / v)


def render(name: str, out: Path) -> Path:
    """Write the picture of a committed scene; returns its path."""
    record = json.loads((DATA / f"{name}.json").read_text())
    data = read_dzt(DATA / f"{name}.DZT").as_float().astype(np.float64)  # (traces, samples)
    data -= np.median(data, axis=0, keepdims=True)  # background: the direct wave and the surface echo
    t = np.arange(data.shape[1]) * record["dt_ns"]
    data *= (1.0 + t / t[-1] * 4.0) ** 2  # a gentle gain so that deep echoes show
    scale = np.percentile(np.abs(data), 99.5) or 1.0
    img = np.clip(127.5 + 127.5 * data.T / scale, 0, 255).astype(np.uint8)
    sx, sy = max(1, 600 // data.shape[0]), max(1, 500 // data.shape[1])
    img = cv2.cvtColor(cv2.resize(img, (data.shape[0] * sx, data.shape[1] * sy), interpolation=cv2.INTER_NEAREST),
                       cv2.COLOR_GRAY2BGR)
    targets = [(p["x_m"], p["depth_m"], p["radius_m"], (0, 0, 255)) for p in record["pipes"]]
    targets += [(r["x_m"], r["depth_m"], r["radius_m"], (0, 200, 255)) for r in record["rebars"]]
    for x, d, r, colour in targets:
        times = arrival_ns(record, x, d, r) + record["source_peak_ns"]
        pts = np.stack([np.arange(data.shape[0]) * sx + sx // 2, times / record["dt_ns"] * sy], axis=1)
        cv2.polylines(img, [pts.round().astype(np.int32).reshape(-1, 1, 2)], False, colour, 1)
        pts[:, 1] = (straight_ns(record, x, d, r) + record["source_peak_ns"]) / record["dt_ns"] * sy
        cv2.polylines(img, [pts.round().astype(np.int32).reshape(-1, 1, 2)], False, (255, 128, 0), 1)
    if record["slab_bottom_m"] is not None:
        h, off = record["antenna"]["height_m"], record["antenna"]["tx_rx_offset_m"]
        tb = 2.0 * h / C + 2.0 * np.hypot(record["slab_bottom_m"], off / 2) / record["velocity_m_per_ns"]
        y = round((tb + record["source_peak_ns"]) / record["dt_ns"] * sy)
        cv2.line(img, (0, y), (img.shape[1] // 8, y), (0, 255, 0), 2)
    label = f"{name}: {record['frequency_mhz']:g} MHz, v {record['velocity_m_per_ns']:.3f} m/ns, {t[-1]:.1f} ns"
    cv2.putText(img, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 0), 1)
    cv2.imwrite(str(out), img)
    return out


if __name__ == "__main__":
    target = Path(sys.argv[2]) if len(sys.argv) > 2 else WORK / f"{sys.argv[1]}.png"
    print(render(sys.argv[1], target))
