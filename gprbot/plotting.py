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

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gprbot.atomic_files import write_bytes_atomic
from gprbot.errors import DataFormatError

DPI = 100


def new_figure(size_in: tuple[float, float]) -> Figure:
    """A figure on an Agg canvas (no pyplot, no display), laid out to fit its labels."""
    fig = Figure(figsize=size_in, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_png(fig: Figure, path: str | os.PathLike[str]) -> None:
    """Render the figure to PNG and write it atomically; an unwritable path is a DataFormatError naming it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    try:
        write_bytes_atomic(path, buffer.getvalue())
    except OSError as exc:
        raise DataFormatError(f"cannot write PNG {path}: {exc}; check that its directory exists and is writable"
                              ) from exc
