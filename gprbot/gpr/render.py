"""PNG pictures of B-scans and cross-sections (matplotlib, Agg), drawn as a GPR analyst reads them.

The B-scan has two-way time on the left and depth (at the velocity used) on the right, a colour bar
and a note of the processing; the horizontal axis is the site coordinate the line runs along, so a
backward line reads left to right like `map.png`. The cross-section states its velocity's provenance
and its vertical exaggeration, and labels each pipe with the depth of its centre and its diameter.
Colours: the mask outline is green, the truth outline (if given) red, pipes yellow crosses, rebars magenta.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gprbot.gpr.bscan import BScan, CrossSection
from gprbot.gpr.migration import envelope
from gprbot.plotting import new_figure, placed_axes, save_png

GREEN, RED, YELLOW, MAGENTA = "#00c800", "#ff0000", "#ffdc00", "#ff00ff"
_STEP_NAMES = {"dewow": "dewow", "background": "background removed"}
_FIG_SIZE_IN = (10.0, 5.0)
_SECTION_WIDTH_IN = 7.85  # the image's width in a 10-inch figure (0.8 in of depth labels, 1.35 in of colour bar)


@dataclass(frozen=True)
class SiteAxis:
    """How along-track metres map onto the site axis a line runs along (x or y), for drawing."""

    name: str  # "x" or "y"
    origin_m: float  # site coordinate at along-track 0
    sign: float  # +1 when the site coordinate grows with along-track distance

    def of(self, along_m: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Site coordinate(s) of along-track distance(s)."""
        return np.asarray(self.origin_m + self.sign * np.asarray(along_m, dtype=np.float64))

    @property
    def label(self) -> str:
        """Axis label saying which way the robot drove."""
        if self.name == "along":
            return "distance from the first trace (m)"
        way = "robot drove →" if self.sign > 0 else "robot drove ←"
        return f"site {self.name} (m)   [{way}]"


ALONG_TRACK = SiteAxis("along", 0.0, 1.0)


def site_axis(bscan: BScan) -> SiteAxis:
    """The site axis (x or y) a line mostly runs along, and its direction along the line."""
    along = bscan.along_track_m()
    p = np.asarray(bscan.positions, dtype=np.float64)
    span = np.ptp(p[:, :2], axis=0)
    k = int(np.argmax(span))
    slope = float(np.polyfit(along, p[:, k], 1)[0]) if np.ptp(along) > 0 else 1.0
    sign = 1.0 if slope >= 0 else -1.0
    # origin: the site coordinate at along = 0, from the least-squares line (jitter-free)
    origin = float(np.mean(p[:, k] - sign * along))
    return SiteAxis("xy"[k], origin, sign)


def processing_note(processing: tuple[str, ...]) -> str:
    """The preprocessing steps in words, e.g. 'dewow, background removed, gain t^1 (cap 100×)'."""
    words = []
    for step in processing:
        if step.startswith("gain:"):
            _, power, cap = step.split(":")
            words.append(f"gain t^{float(power):g} (cap {float(cap):g}×)")
        elif step in _STEP_NAMES:
            words.append(_STEP_NAMES[step])
        elif step.startswith("direct:"):
            continue  # the direct wave's polarity is bookkeeping, not processing
        else:
            words.append(step)
    return ", ".join(words) if words else "raw (no processing)"


def _uniform_columns(coord: NDArray[np.float64], spacing: float) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """A uniform grid over coord's range and, per grid column, the nearest trace (handles speed changes)."""
    order = np.argsort(coord, kind="stable")
    sorted_coord = coord[order]
    n = max(2, round(float(np.ptp(coord)) / max(spacing, 1e-6)) + 1)
    grid = np.linspace(sorted_coord[0], sorted_coord[-1], n)
    idx = np.clip(np.searchsorted(sorted_coord, grid), 1, len(coord) - 1)
    left_closer = (grid - sorted_coord[idx - 1]) < (sorted_coord[idx] - grid)
    nearest = np.where(left_closer, idx - 1, idx)
    return grid, order[nearest]


def bscan_image(bscan: BScan, site_frame: bool = True) -> tuple[SiteAxis, NDArray[np.float64], NDArray[np.float64]]:
    """The B-scan as drawn: its horizontal axis, the uniform grid on it (m), and (samples, columns) amplitudes."""
    from gprbot.gpr.bscan import grid_spacing_m

    axis = site_axis(bscan) if site_frame else ALONG_TRACK
    along = bscan.along_track_m()
    grid, columns = _uniform_columns(axis.of(along), grid_spacing_m(along))
    return axis, grid, np.asarray(bscan.data, dtype=np.float64)[columns].T


def write_bscan_png(
    path: str | Path, bscan: BScan, velocity_m_per_ns: float | None = None,
    velocity_note: str = "", title: str = "B-scan", site_frame: bool = True,
) -> None:
    """The B-scan: site coordinate across, two-way time (and depth at the velocity) down, colour bar, processing.

    site_frame=False (a file without poses): distance from the first trace across instead.
    """
    axis, grid, data = bscan_image(bscan, site_frame)
    n_samples = data.shape[0]
    t0 = bscan.t0_ns if math.isfinite(bscan.t0_ns) else 0.0
    t_top, t_bottom = -t0, (n_samples - 1) * bscan.dt_ns - t0
    clip = float(np.percentile(np.abs(data), 99.5)) or 1.0

    fig = new_figure(_FIG_SIZE_IN, fixed_layout=True)
    # right margin: the depth axis's ticks and label, then the colour bar and its label
    ax, bar_ax = placed_axes(fig, 0.8, 2.0 if velocity_m_per_ns else 1.35, 0.85, 0.4,
                             bar_gap_in=0.95 if velocity_m_per_ns else 0.2)
    image = ax.imshow(data, cmap="gray", vmin=-clip, vmax=clip, aspect="auto", interpolation="nearest",
                      extent=(float(grid[0]), float(grid[-1]), t_bottom, t_top))
    ax.set_xlabel(axis.label)
    ax.set_ylabel("two-way time after time zero (ns)")
    if velocity_m_per_ns:
        v = velocity_m_per_ns

        def to_depth(t: ArrayLike) -> NDArray[np.float64]:
            return np.asarray(t, dtype=np.float64) * v / 2.0

        def to_time(d: ArrayLike) -> NDArray[np.float64]:
            return 2.0 * np.asarray(d, dtype=np.float64) / v

        depth_axis = ax.secondary_yaxis("right", functions=(to_depth, to_time))
        depth_axis.set_ylabel(f"depth (m) at v = {v:.4f} m/ns")
    colour_bar = fig.colorbar(image, cax=bar_ax)
    colour_bar.set_label("amplitude (processed, clipped at 99.5 %)")
    ax.set_title(f"{title}: {bscan.data.shape[0]} traces × {n_samples} samples, dt = {bscan.dt_ns:.3g} ns")
    velocity = f"; velocity {velocity_note}" if velocity_m_per_ns and velocity_note else ""
    footer = f"processing: {processing_note(bscan.processing)}; time zero at {t0:.2f} ns of the record{velocity}"
    fig.text(0.5, 0.02, textwrap.fill(footer, 150), fontsize=8, color="#444444", ha="center", va="bottom")
    save_png(fig, path)


def vertical_exaggeration(x_span_m: float, z_span_m: float, max_ratio: float = 3.5) -> float:
    """1 (true scale) unless the section is wider than max_ratio × its depth; then a 1-2-5 factor that fits."""
    ratio = x_span_m / max(z_span_m, 1e-9)
    if ratio <= max_ratio:
        return 1.0
    needed = ratio / max_ratio
    power = 10.0 ** math.floor(math.log10(needed))
    return next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= needed * 0.999)


def display_clip(picture: NDArray[np.float64]) -> float:
    """The envelope value the section's grey scale tops out at: the 99.5th percentile of its interior rows.

    The surface row (the direct wave's residue) and the last rows (migration's edge, where a record's gained tail
    is summed along truncated curves) outshine every target on a long line: a real 26 m trench line drew all
    black under them.
    """
    rows = picture.shape[0]
    edge = max(1, rows // 20)
    interior = picture[edge:rows - edge] if rows > 2 * edge + 1 else picture
    return float(np.percentile(interior, 99.5)) or 1.0


def write_cross_section_png(
    path: str | Path, section: CrossSection, truth_mask: NDArray[np.bool_] | None = None,
    bscan: BScan | None = None, velocity_note: str | None = None, title: str = "Cross-section",
) -> None:
    """The migrated image's envelope, mask outline, truth outline, pipes (centre depth, diameter) and rebars.

    With the line's B-scan the horizontal axis is the site coordinate (as on the map); velocity_note is the
    velocity's true provenance (the survey's, when the section was interpreted at a velocity found for all lines).
    """
    axis = site_axis(bscan) if bscan is not None else ALONG_TRACK
    x = axis.of(section.x_m)
    z = np.asarray(section.z_m, dtype=np.float64)
    picture = np.asarray(envelope(section.image), dtype=np.float64)
    clip = display_clip(picture)
    left, right = (0, -1) if axis.sign > 0 else (-1, 0)
    extent = (float(x[left]), float(x[right]), float(z[-1]), float(z[0]))
    exaggeration = vertical_exaggeration(abs(extent[1] - extent[0]), extent[2] - extent[3])
    # the figure as tall as the section drawn at its aspect (plus titles), so the colour bar fits the image
    drawn_ratio = exaggeration * (extent[2] - extent[3]) / max(abs(extent[1] - extent[0]), 1e-9)
    height_in = min(max(_SECTION_WIDTH_IN * drawn_ratio + 1.4, 3.2), 9.0)

    fig = new_figure((_FIG_SIZE_IN[0], height_in), fixed_layout=True)
    ax, bar_ax = placed_axes(fig, 0.8, 1.35, 0.85, 0.55)
    ax.set_anchor("W")
    shown = picture if axis.sign > 0 else picture[:, ::-1]
    image = ax.imshow(shown, cmap="gray", vmin=0.0, vmax=clip, extent=extent, interpolation="nearest")
    ax.set_aspect(exaggeration)
    xx, zz = np.meshgrid(x, z)
    if truth_mask is not None and np.any(truth_mask):
        ax.contour(xx, zz, np.asarray(truth_mask, np.float64), levels=[0.5], colors=RED, linewidths=1.0)
    if np.any(section.mask):
        ax.contour(xx, zz, np.asarray(section.mask, np.float64), levels=[0.5], colors=GREEN, linewidths=1.0)
    for d in section.detections:
        px = float(axis.of(d.x_m))
        ax.plot([px], [d.depth_m], marker="+", markersize=12, markeredgewidth=2, color=YELLOW)
        size = f"Ø {d.radius_m * 200:.1f} cm" if d.radius_m > 0 else "Ø not measured"  # the interpreter's 0
        size += " (mask)" if d.radius_from_mask else "" if d.radius_supported else " (?)"  # (?): the middle of
        # what the curve allows
        ax.annotate(f"{size}, cover {d.depth_m - d.radius_m:.2f} m", (px, d.depth_m),
                    xytext=(6, -10), textcoords="offset points", color=YELLOW, fontsize=8,
                    bbox={"boxstyle": "round,pad=0.15", "fc": "black", "alpha": 0.6, "lw": 0})
    for r in section.rebars:
        ax.plot([float(axis.of(r.x_m))], [r.depth_m], marker="o", markersize=5, fillstyle="none", color=MAGENTA)
    ax.set_xlabel(axis.label)
    ax.set_ylabel("depth below the surface (m)")
    colour_bar = fig.colorbar(image, cax=bar_ax)
    colour_bar.set_label("migrated envelope")
    kind = velocity_note or ("estimated" if section.velocity_estimated else "given")
    scale = "true scale" if exaggeration == 1.0 else f"vertical exaggeration ×{exaggeration:g}"
    rebars = f", {len(section.rebars)} rebars" if section.rebars else ""
    ax.set_title(textwrap.fill(f"{title}: v = {section.velocity_m_per_ns:.4f} m/ns ({kind}), "
                               f"{len(section.detections)} pipes{rebars}; {scale}", 80), fontsize=10)
    legend = "green: cross-section mask" + ("   red: truth" if truth_mask is not None else "")
    fig.text(0.5, 0.01, textwrap.fill(f"{legend}   yellow +: pipe centre (label: diameter, (?) where the data do not "
                                      "measure it, (mask) from MigrationNet's pipe mask, depth of cover to its top)   "
                                      "magenta o: rebar", 120), fontsize=8, color="#444444", ha="center", va="bottom")
    save_png(fig, path)
