"""matplotlib for result pictures: figures without pyplot (thread-safe, no GUI), saved atomically as PNG.

The object-oriented API (`Figure` + the Agg canvas) keeps no global state, so pictures can be drawn in
the worker thread that writes a run's outputs, never on the event loop and never through a display.
"""

from __future__ import annotations

import io
import os

# Under systemd (ProtectHome=yes, a read-only /) matplotlib's ~/.config/matplotlib is not writable: it
# would build its font cache in a temp dir on every start, with a warning. The unit's StateDirectory is.
if "MPLCONFIGDIR" not in os.environ and os.environ.get("STATE_DIRECTORY"):
    os.environ["MPLCONFIGDIR"] = os.path.join(os.environ["STATE_DIRECTORY"].split(":")[0], "matplotlib")

from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gprbot.atomic_files import write_bytes_atomic
from gprbot.errors import DataFormatError

DPI = 100


def new_figure(size_in: tuple[float, float], fixed_layout: bool = False) -> Figure:
    """A figure on an Agg canvas (no pyplot, no display); constrained layout unless the caller places its axes
    (fixed_layout: one draw instead of two — half the time of the pictures drawn for every survey line)."""
    fig = Figure(figsize=size_in, dpi=DPI, layout=None if fixed_layout else "constrained")
    FigureCanvasAgg(fig)
    return fig


def placed_axes(fig: Figure, left_in: float, right_in: float, bottom_in: float, top_in: float,
                bar_gap_in: float = 0.15, bar_width_in: float = 0.18) -> tuple[Axes, Axes]:
    """An axes with margins in inches and a colour-bar axes beside it (bar_gap_in right of the axes)."""
    width, height = fig.get_size_inches()
    ax = fig.add_axes((left_in / width, bottom_in / height, 1 - (left_in + right_in) / width,
                       1 - (bottom_in + top_in) / height))
    bar = fig.add_axes((1 - (right_in - bar_gap_in) / width, bottom_in / height, bar_width_in / width,
                        1 - (bottom_in + top_in) / height))
    return ax, bar


def save_png(fig: Figure, path: str | os.PathLike[str]) -> None:
    """Render the figure to PNG and write it atomically; an unwritable path is a DataFormatError naming it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    try:
        write_bytes_atomic(path, buffer.getvalue())
    except OSError as exc:
        raise DataFormatError(f"cannot write PNG {path}: {exc}; check that its directory exists and is writable"
                              ) from exc
