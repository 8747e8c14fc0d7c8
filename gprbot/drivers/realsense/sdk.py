"""The optional librealsense binding, imported in one place: its absence is reported when a RealSense
is used, not when gprbot is imported."""

from __future__ import annotations

from typing import Any

from gprbot.errors import DriverError

try:
    import pyrealsense2 as rs
except ImportError:  # wheels exist for x86_64 only; the driver then reports it at start
    rs = None


def require_pyrealsense() -> Any:
    """The pyrealsense2 module, or a DriverError saying how to get it."""
    if rs is None:
        raise DriverError("pyrealsense2 is not installed (wheels exist for x86_64): pip install pyrealsense2")
    return rs
