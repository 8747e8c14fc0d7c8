"""RealSense recordings made without a camera: an `rs.software_device` shaped like a D435i, fed with
given IMU samples and RGB-D frames and recorded by `rs.recorder`.

librealsense 2.59 records only rosbag2 SQLite files and refuses any name not ending in `.db3`; it still
plays legacy ROS1 `.bag` files. Depth and colour are stored PNG-compressed (lossless) with `compress`,
raw otherwise (the default: PNG costs ~25 ms per 424x240 pair of noise frames). Samples are pushed in
timestamp order across streams, so a recording plays back in time order.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, NamedTuple, TypedDict, Unpack

import numpy as np
from numpy.typing import NDArray

from gprbot.drivers.realsense.readings import Intrinsics
from gprbot.drivers.realsense.sdk import require_pyrealsense
from gprbot.errors import DriverError


class RecordingRates(NamedTuple):
    """Nominal stream rates written into the recording's stream profiles."""

    gyro_hz: int = 400
    accel_hz: int = 250
    fps: int = 30


DEFAULT_RATES = RecordingRates()


class CameraOptions(TypedDict, total=False):
    """The optional settings of a `SoftwareD435i`, which `write_recording` passes on to it."""

    color_intrinsics: Intrinsics | None
    depth_to_color_m: tuple[float, float, float]
    depth_scale: float
    serial: str
    color_format: str


# Stream uids must be unique within the device; they also order samples of equal timestamps.
_UID = {"depth": 0, "color": 1, "gyro": 2, "accel": 3}


class SoftwareD435i:
    """An `rs.software_device` shaped like a D435i: Stereo Module (depth z16), RGB Camera (bgr8) and
    Motion Module (gyro, accel as motion_xyz32f), fed frame by frame with `push`."""

    def __init__(
        self,
        width: int,
        height: int,
        intrinsics: Intrinsics,
        rates: RecordingRates = DEFAULT_RATES,
        *,
        color_intrinsics: Intrinsics | None = None,
        depth_to_color_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        depth_scale: float = 0.001,
        serial: str = "000000000000",
        color_format: str = "bgr8",
    ):
        sdk = self._sdk = require_pyrealsense()
        self.depth_scale = depth_scale
        self.device = sdk.software_device()
        self.device.register_info(sdk.camera_info.name, "Intel RealSense D435I")
        self.device.register_info(sdk.camera_info.serial_number, serial)
        depth = self.device.add_sensor("Stereo Module")
        color = self.device.add_sensor("RGB Camera")
        motion = self.device.add_sensor("Motion Module")
        depth.add_read_only_option(sdk.option.depth_units, depth_scale)
        self.sensors = {"depth": depth, "color": color, "gyro": motion, "accel": motion}
        color_intr = color_intrinsics or intrinsics
        self.profiles = {
            "depth": depth.add_video_stream(
                _video_stream(sdk, "depth", "z16", 2, width, height, rates.fps, intrinsics)),
            "color": color.add_video_stream(
                _video_stream(sdk, "color", color_format, 3, width, height, rates.fps, color_intr)),
            "gyro": motion.add_motion_stream(_motion_stream(sdk, "gyro", rates.gyro_hz)),
            "accel": motion.add_motion_stream(_motion_stream(sdk, "accel", rates.accel_hz)),
        }
        extrinsics = sdk.extrinsics()
        extrinsics.rotation = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        extrinsics.translation = list(depth_to_color_m)
        self.profiles["depth"].register_extrinsics_to(self.profiles["color"], extrinsics)
        self._numbers = dict.fromkeys(_UID, 0)

    def start(self) -> None:
        """Open and start every sensor with a callback that ignores frames (for a recorder to tap)."""
        unique = {id(s): s for s in self.sensors.values()}.values()
        for sensor in unique:
            sensor.open([p for name, p in self.profiles.items() if self.sensors[name] is sensor])
            sensor.start(lambda frame: None)

    def stop(self) -> None:
        """Stop and close the sensors started by `start`."""
        for sensor in {id(s): s for s in self.sensors.values()}.values():
            sensor.stop()
            sensor.close()

    def push(self, stream: str, t_s: float, data: NDArray[Any], number: int | None = None) -> None:
        """Deliver one sample of `stream` stamped t_s (hardware clock); numbers count up unless given."""
        number = self._numbers[stream] if number is None else number
        self._numbers[stream] = number + 1
        frame: Any
        if stream in ("gyro", "accel"):
            frame = self._sdk.software_motion_frame()
            vector = self._sdk.vector()
            vector.x, vector.y, vector.z = (float(v) for v in data)
            frame.data = vector
            frame.profile = self.profiles[stream].as_motion_stream_profile()
        else:
            frame = self._sdk.software_video_frame()
            frame.pixels = data
            frame.bpp = data.itemsize * (data.shape[2] if data.ndim == 3 else 1)
            frame.stride = data.shape[1] * frame.bpp
            frame.profile = self.profiles[stream].as_video_stream_profile()
            if stream == "depth":
                frame.depth_units = self.depth_scale
        frame.timestamp, frame.frame_number = t_s * 1000.0, number
        frame.domain = self._sdk.timestamp_domain.hardware_clock
        if stream in ("gyro", "accel"):
            self.sensors[stream].on_motion_frame(frame)
        else:
            self.sensors[stream].on_video_frame(frame)


def write_recording(
    path: str | Path,
    imu: Iterable[Any],
    frames: Sequence[tuple[float, NDArray[np.uint8], NDArray[np.uint16]]],
    intrinsics: Intrinsics,
    rates: RecordingRates = DEFAULT_RATES,
    *,
    compress: bool = False,
    **options: Unpack[CameraOptions],
) -> Path:
    """Record IMU samples (t s, gyro rad/s, accel m/s²) and frames (t s, colour BGR, depth) to a .db3.

    `imu` items are ImuSample-like (attributes or a tuple t, gyro, accel; either may be None). Device
    timestamps are t in milliseconds on the hardware clock; frame numbers count from 0 per stream.
    `options` shape the camera as in `SoftwareD435i`: `color_format` "rgb8" records the colour
    images as RGB (as some tools do). Returns the file written: `path` with its suffix made `.db3`.
    """
    sdk = require_pyrealsense()
    target = Path(path).with_suffix(".db3")
    target.unlink(missing_ok=True)  # the recorder will not overwrite
    events = _timeline(imu, frames)
    height, width = frames[0][2].shape if frames else (0, 0)
    camera = SoftwareD435i(width, height, intrinsics, rates, **options)
    try:
        recorder = sdk.recorder(str(target), camera.device, compress)
    except RuntimeError as exc:
        raise DriverError(f"cannot record to {target}: {exc}") from exc
    camera.start()
    for t, stream, data in events:
        camera.push(stream, t, data)
    camera.stop()
    recorder.pause()
    del recorder  # the file is finalised when the recorder is destroyed
    return target


def _timeline(imu: Iterable[Any], frames: Sequence[tuple[float, Any, Any]]) -> list[tuple[float, str, Any]]:
    """Every sample of every stream as (t, stream, data), in time order (ties: depth, colour, gyro, accel)."""
    events: list[tuple[float, int, str, Any]] = []
    for item in imu:
        t, gyro, accel = item if isinstance(item, tuple) else (item.t, item.gyro, item.accel)
        if gyro is not None:
            events.append((float(t), _UID["gyro"], "gyro", np.asarray(gyro, dtype=np.float64)))
        if accel is not None:
            events.append((float(t), _UID["accel"], "accel", np.asarray(accel, dtype=np.float64)))
    shape = frames[0][2].shape if frames else None
    for t, color, depth in frames:
        if depth.shape != shape or color.shape != (*depth.shape, 3):
            raise ValueError(f"frames must share one size: colour (h, w, 3) uint8 and depth (h, w) {shape}")
        events.append((float(t), _UID["depth"], "depth", np.ascontiguousarray(depth, dtype=np.uint16)))
        events.append((float(t), _UID["color"], "color", np.ascontiguousarray(color, dtype=np.uint8)))
    events.sort(key=lambda e: (e[0], e[1]))
    return [(t, stream, data) for t, _, stream, data in events]


def _video_stream(
    sdk: Any, name: str, fmt: str, bpp: int, width: int, height: int, fps: int, intr: Intrinsics
) -> Any:
    intrinsics = sdk.intrinsics()
    intrinsics.width, intrinsics.height = width, height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = intr
    intrinsics.model = sdk.distortion.none
    intrinsics.coeffs = [0.0] * 5
    stream = sdk.video_stream()
    stream.type = getattr(sdk.stream, name)
    stream.index, stream.uid = 0, _UID[name]
    stream.width, stream.height, stream.fps, stream.bpp = width, height, fps, bpp
    stream.fmt = getattr(sdk.format, fmt)
    stream.intrinsics = intrinsics
    return stream


def _motion_stream(sdk: Any, name: str, rate_hz: int) -> Any:
    intrinsics = sdk.motion_device_intrinsic()
    intrinsics.data = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    intrinsics.noise_variances = [0.0, 0.0, 0.0]
    intrinsics.bias_variances = [0.0, 0.0, 0.0]
    stream = sdk.motion_stream()
    stream.type = getattr(sdk.stream, name)
    stream.index, stream.uid, stream.fps = 0, _UID[name], rate_hz
    stream.fmt = sdk.format.motion_xyz32f
    stream.intrinsics = intrinsics
    return stream
