"""The blocking SDK side of the RealSense driver: a D435i or a recording, its frames as numpy readings.

`RealsenseSource` opens the sensors directly rather than through `rs.pipeline`: the pipeline's syncer
keeps one frame per stream, so at 400 Hz it drops most IMU samples, and with a frame callback it stalls
non-real-time playback. Readings are handed to a sink from librealsense's own threads; a recording plays
as fast as the sink takes them (`set_real_time(False)`), so a blocking sink is backpressure, not loss.
The readings are defined in `readings`, the depth-to-colour registration in `registration`.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.config import SIMULATED, RealsenseConfig
from gprbot.drivers.realsense.clock import FramePairer
from gprbot.drivers.realsense.depth_to_color import DepthToColor, same_geometry
from gprbot.drivers.realsense.readings import Intrinsics, MotionReading, Reading, RgbdReading, Sink, SourceEvent
from gprbot.drivers.realsense.sdk import require_pyrealsense
from gprbot.errors import DriverError

__all__ = [
    "ACCEL_RATES_HZ", "GYRO_RATES_HZ", "DepthToColor", "Intrinsics", "MotionReading", "Reading", "RealsenseSource",
    "RgbdReading", "Sink", "SourceEvent", "require_pyrealsense", "same_geometry",
]

GYRO_RATES_HZ = (200, 400)
ACCEL_RATES_HZ = (63, 250)
_HELP_DEVICE = (
    "plug the D435i into a USB 3 port (blue), check that librealsense's udev rules "
    "(99-realsense-libusb.rules) are installed, and run `rs-enumerate-devices`"
)


class RealsenseSource:
    """A D435i (cfg.source "device" or a serial number) or a recording (cfg.playback) feeding a sink.

    `device` replaces the search for a camera (tests pass an `rs.software_device`, which a context does
    not enumerate); the live path is then the same as with a real D435i.
    """

    def __init__(self, cfg: RealsenseConfig, sink: Sink, clock: Callable[[], float], device: Any = None):
        self.cfg, self._sink, self._clock, self._given_device = cfg, sink, clock, device
        self.is_playback = cfg.playback is not None
        self.streams: tuple[str, ...] = ()
        self.device_info: dict[str, str] = {}
        self._finished = threading.Event()
        self._pair_lock = threading.Lock()
        self._pairer: FramePairer[tuple[Any, float]] = FramePairer(500.0 / max(cfg.fps, 1))
        self._register: DepthToColor | None = None
        self._intrinsics: Intrinsics = (0.0, 0.0, 0.0, 0.0)
        self._device: Any = None
        self._keep: list[Any] = []  # context and pipeline: alive as long as the sensors stream
        self._opened: list[Any] = []
        self._started: list[Any] = []
        self._lifecycle = threading.RLock()  # open() runs in one worker thread, close() maybe in another
        self._closed = False

    def open(self) -> None:
        """Open the device or recording and start streaming into the sink (blocking)."""
        with self._lifecycle:
            if self._closed:
                raise DriverError("this RealSense source was closed; make a new one")
            sdk = require_pyrealsense()
            ctx = sdk.context()
            selection = self._open_recording(sdk, ctx) if self.is_playback else self._open_device(sdk, ctx)
            self._prepare_rgbd(selection)
            try:
                self._start(selection, ctx)
            except RuntimeError as exc:
                self.close()
                what = f"the recording {self.cfg.playback}" if self.is_playback else "the RealSense"
                raise DriverError(f"{what} would not start streaming: {exc}") from exc

    def wait_finished(self, timeout_s: float | None = None) -> bool:
        """Block until a recording has played to its end (or the source is closed)."""
        return self._finished.wait(timeout_s)

    def close(self) -> None:
        """Stop and close the sensors (blocking; waits for callbacks in flight)."""
        with self._lifecycle:
            self._closed = True
            self._finished.set()
            for sensor in self._started:
                with contextlib.suppress(RuntimeError):  # the device may already be gone
                    sensor.stop()
            for sensor in self._opened:
                with contextlib.suppress(RuntimeError):
                    sensor.close()
            self._started, self._opened, self._keep, self._register = [], [], [], None

    def _start(self, selection: list[tuple[Any, list[Any]]], ctx: Any) -> None:
        playback = self._device.as_playback() if self.is_playback else None
        for sensor, profiles in selection:
            sensor.open(profiles)
            self._opened.append(sensor)
        if playback is not None:
            playback.set_real_time(False)
            playback.pause()  # else the frames read before the last sensor starts are lost
        for sensor, _ in selection:
            sensor.start(self._on_frame)
            self._started.append(sensor)
        if playback is not None:
            playback.set_status_changed_callback(self._on_status)
            playback.resume()
        elif self._given_device is None:
            ctx.set_devices_changed_callback(self._on_devices_changed)

    def _open_recording(self, sdk: Any, ctx: Any) -> list[tuple[Any, list[Any]]]:
        path = Path(str(self.cfg.playback))
        if not path.is_file():
            raise DriverError(f"realsense.playback: no recording at {path}; check the path")
        config, pipeline = sdk.config(), sdk.pipeline(ctx)
        try:
            config.enable_device_from_file(str(path), repeat_playback=False)
            self._device = config.resolve(sdk.pipeline_wrapper(pipeline)).get_device()
        except RuntimeError as exc:
            raise DriverError(
                f"realsense.playback: cannot read {path} as a RealSense recording ({exc}); librealsense "
                f"{sdk.__version__} plays .db3 (rosbag2) and legacy .bag files recorded by librealsense"
            ) from exc
        self._keep = [ctx, pipeline]
        self.device_info = {"source": str(path), **_describe(sdk, self._device)}
        selection = []
        for sensor in self._device.query_sensors():
            profiles = [p for p in sensor.get_stream_profiles() if _stream_name(sdk, p) is not None]
            if profiles:
                selection.append((sensor, profiles))
        if not selection:
            raise DriverError(f"realsense.playback: {path} holds no depth, colour, gyro or accel stream")
        return selection

    def _open_device(self, sdk: Any, ctx: Any) -> list[tuple[Any, list[Any]]]:
        cfg = self.cfg
        if cfg.source == SIMULATED and self._given_device is None:
            raise DriverError(
                'realsense.source is "sim": the simulator provides the camera; set realsense.source to '
                '"device" (or a serial number) or realsense.playback to a recording'
            )
        if cfg.gyro_hz not in GYRO_RATES_HZ or cfg.accel_hz not in ACCEL_RATES_HZ:
            raise DriverError(
                f"realsense.gyro_hz / accel_hz: the D435i runs gyro at {GYRO_RATES_HZ} Hz and accel at "
                f"{ACCEL_RATES_HZ} Hz, not {cfg.gyro_hz} / {cfg.accel_hz}"
            )
        self._device = self._given_device or _find_device(sdk, ctx, cfg.source)
        self._keep = [ctx]
        self.device_info = {"source": "device", **_describe(sdk, self._device)}
        wanted = {
            ("depth", "z16", cfg.width, cfg.height, cfg.fps), ("color", "bgr8", cfg.width, cfg.height, cfg.fps),
            ("gyro", "motion_xyz32f", 0, 0, cfg.gyro_hz), ("accel", "motion_xyz32f", 0, 0, cfg.accel_hz),
        }
        selection: list[tuple[Any, list[Any]]] = []
        found: set[tuple[str | None, str, int, int, int]] = set()
        for sensor in self._device.query_sensors():
            profiles = []
            for profile in sensor.get_stream_profiles():
                if (mode := _mode(sdk, profile)) in wanted - found:
                    profiles.append(profile)
                    found.add(mode)
            if profiles:
                selection.append((sensor, profiles))
        if missing := sorted(f"{name} {fmt} {w}x{h}@{hz}" for name, fmt, w, h, hz in wanted - found):
            usb = self.device_info.get("usb", "?")
            raise DriverError(
                f"the RealSense {self.device_info.get('serial')} (on USB {usb}) offers no {', '.join(missing)} "
                f"mode; check realsense.width/height/fps against `rs-enumerate-devices`, and that the camera "
                "is on a USB 3 port (on USB 2 the D435i offers few modes)"
            )
        return selection

    def _prepare_rgbd(self, selection: list[tuple[Any, list[Any]]]) -> None:
        sdk = require_pyrealsense()
        by_name = {_stream_name(sdk, p): p for _, profiles in selection for p in profiles}
        self.streams = tuple(sorted(name for name in by_name if name is not None))
        depth, color = by_name.get("depth"), by_name.get("color")
        if depth is None or color is None:
            return
        self._pairer = FramePairer(500.0 / max(color.fps(), 1))
        color_intr = color.as_video_stream_profile().get_intrinsics()
        self._intrinsics = (color_intr.fx, color_intr.fy, color_intr.ppx, color_intr.ppy)
        if not same_geometry(depth, color):
            self._register = DepthToColor()

    def _on_frame(self, frame: Any) -> None:
        received = self._clock()
        try:
            sdk = require_pyrealsense()
            name = _stream_name(sdk, frame.get_profile())
            if name in ("gyro", "accel"):
                data = frame.as_motion_frame().get_motion_data()
                self._sink(MotionReading(
                    name, frame.get_frame_number(), frame.get_timestamp(),
                    frame.get_frame_timestamp_domain().name, received,
                    np.array([data.x, data.y, data.z], dtype=np.float64),
                ))
            elif name in ("depth", "color"):
                with self._pair_lock:
                    pair = self._pairer.offer(name, frame.get_timestamp(), (frame, received))
                    reading = self._rgbd(*pair) if pair is not None else None
                if reading is not None:
                    self._sink(reading)  # outside the lock: a playback sink blocks while the consumer lags
        except Exception as exc:  # nothing may escape into librealsense's thread
            self._sink(SourceEvent("error", f"{type(exc).__name__}: {exc}"))

    def _rgbd(self, depth_item: tuple[Any, float], color_item: tuple[Any, float]) -> RgbdReading:
        depth_frame, received = depth_item
        color_frame = color_item[0]
        registered = self._register(depth_frame, color_frame) if self._register else depth_frame
        color = np.asanyarray(color_frame.get_data())
        if color_frame.get_profile().format().name == "rgb8":
            color = color[..., ::-1]  # published BGR, as OpenCV and messages.RgbdFrame have it
        return RgbdReading(
            depth_number=depth_frame.get_frame_number(),
            color_number=color_frame.get_frame_number(),
            device_ms=depth_frame.get_timestamp(),
            domain=depth_frame.get_frame_timestamp_domain().name,
            host_s=received,
            color=np.ascontiguousarray(color, dtype=np.uint8).copy(),
            depth=np.array(np.asanyarray(registered.get_data()), dtype=np.uint16),
            depth_scale=float(depth_frame.as_depth_frame().get_units()),
            intrinsics=self._intrinsics,
        )

    def _on_status(self, status: Any) -> None:
        if status == require_pyrealsense().playback_status.stopped:
            self._finished.set()

    def _on_devices_changed(self, info: Any) -> None:
        if self._device is not None and info.was_removed(self._device):
            self._sink(SourceEvent("lost", "the RealSense was disconnected; " + _HELP_DEVICE))



def _stream_name(sdk: Any, profile: Any) -> str | None:
    """Our name of a stream profile we can convert, or None (infrared, unsupported formats)."""
    kind, fmt = profile.stream_type(), profile.format()
    if kind == sdk.stream.depth and fmt == sdk.format.z16:
        return "depth"
    if kind == sdk.stream.color and fmt in (sdk.format.rgb8, sdk.format.bgr8):
        return "color"
    if kind in (sdk.stream.gyro, sdk.stream.accel) and fmt == sdk.format.motion_xyz32f:
        return "gyro" if kind == sdk.stream.gyro else "accel"
    return None


def _mode(sdk: Any, profile: Any) -> tuple[str | None, str, int, int, int]:
    """(stream, format, width, height, rate) of a profile; width and height 0 for motion streams."""
    width = height = 0
    if profile.is_video_stream_profile():
        video = profile.as_video_stream_profile()
        width, height = video.width(), video.height()
    return _stream_name(sdk, profile), profile.format().name, width, height, profile.fps()


def _find_device(sdk: Any, ctx: Any, source: str) -> Any:
    """The first RealSense attached ("device") or the one with serial number `source`."""
    devices = list(ctx.query_devices())
    serials = [d.get_info(sdk.camera_info.serial_number) for d in devices]
    if not devices:
        raise DriverError(f"no RealSense camera found: {_HELP_DEVICE}")
    if source == "device":
        return devices[0]
    if source not in serials:
        raise DriverError(f"realsense.source: no RealSense with serial {source} (found {serials})")
    return devices[serials.index(source)]


def _describe(sdk: Any, device: Any) -> dict[str, str]:
    """Name, serial, firmware and USB link of a device, for the run log's header and error messages."""
    info = {}
    fields = (("name", "name"), ("serial", "serial_number"), ("firmware", "firmware_version"),
              ("usb", "usb_type_descriptor"))
    for key, field_name in fields:
        option = getattr(sdk.camera_info, field_name)
        if device.supports(option):
            info[key] = device.get_info(option)
    return info
