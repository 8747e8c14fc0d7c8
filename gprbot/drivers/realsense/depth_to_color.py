"""Depth mapped into the colour camera when the two do not already share one geometry (librealsense calls it
registration; `reconstruct/register.py` is the other kind: slices into 3D)."""

from __future__ import annotations

from typing import Any

import numpy as np

from gprbot.drivers.realsense.sdk import require_pyrealsense


class DepthToColor:
    """Registers depth frames to the colour camera with librealsense's own `rs.align`."""

    def __init__(self) -> None:
        sdk = require_pyrealsense()
        self._pair: list[Any] = []
        # rs.align takes a frameset; a processing block is the SDK's way to compose one from two frames.
        self._compose = sdk.processing_block(self._composite)
        self._framesets = sdk.frame_queue(1, keep_frames=True)
        self._compose.start(self._framesets)
        self._align = sdk.align(sdk.stream.color)

    def __call__(self, depth: Any, color: Any) -> Any:
        """The depth frame resampled onto the colour image (zero where no depth maps)."""
        self._pair = [depth, color]
        self._compose.invoke(depth)
        frameset = self._framesets.wait_for_frame().as_frameset()
        self._pair = []
        return self._align.process(frameset).get_depth_frame()

    def _composite(self, frame: Any, source: Any) -> None:
        source.frame_ready(source.allocate_composite_frame(self._pair))


def same_geometry(depth: Any, color: Any) -> bool:
    """True when depth already lies on the colour image: equal intrinsics and identity extrinsics."""
    a = depth.as_video_stream_profile().get_intrinsics()
    b = color.as_video_stream_profile().get_intrinsics()
    fields = ("width", "height", "fx", "fy", "ppx", "ppy", "model", "coeffs")
    if any(getattr(a, name) != getattr(b, name) for name in fields):
        return False
    extrinsics = depth.get_extrinsics_to(color)
    return bool(
        np.allclose(extrinsics.rotation, np.eye(3).ravel()) and np.allclose(extrinsics.translation, 0.0)
    )
