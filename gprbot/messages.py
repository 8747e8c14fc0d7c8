"""Every message type that crosses a module boundary, their one registry, and the msgpack codec.

Every message carries `t`: seconds on the host monotonic clock (drivers convert device clocks once).
Arrays travel as (dtype, shape, raw bytes) so that a run log replays bit for bit. REGISTRY says, per
type, whether the daemon logs it and at what rate it is expected (a number, or the config keys whose
sum sets it), so that health compares measured rates against one table and the run-log reader decodes
every type without importing the drivers that publish them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import reduce
from typing import Any

import msgpack
import numpy as np
from numpy.typing import NDArray

from gprbot.errors import ProtocolError


@dataclass(frozen=True)
class Trace:
    """One GPR trace: samples in mV (or raw counts), sample interval dt_ns, time zero at t0_ns."""

    t: float
    number: int
    samples: NDArray[np.float32]
    dt_ns: float
    t0_ns: float = 0.0
    stacks: int = 1


@dataclass(frozen=True)
class Pose:
    """A 6-DOF pose of the robot base in the site frame: position (m) and quaternion (x, y, z, w)."""

    t: float
    position: NDArray[np.float64]
    orientation: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    position_std_m: float = 0.0  # the estimator's 1σ of the horizontal position (largest axis); 0: not given
    yaw_std_rad: float = 0.0  # its 1σ of the heading


@dataclass(frozen=True)
class ImuSample:
    """One IMU reading: angular rate (rad/s) and/or specific force (m/s²) in the IMU frame."""

    t: float
    gyro: NDArray[np.float64] | None = None
    accel: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class WheelSpeeds:
    """Commanded or measured wheel angular speeds (rad/s), one per omni wheel.

    `sample_offsets_s`: for measured speeds read one after another, when each was sampled relative
    to t (≤ 0; None: all at t), so the filter compares each with its velocity at that instant.
    """

    t: float
    speeds: NDArray[np.float64]
    sample_offsets_s: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics (pixels) of an undistorted image."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def matrix(self) -> NDArray[np.float64]:
        """The 3×3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RgbdFrame:
    """One colour image (BGR uint8) with metric depth aligned to it (float32 m, 0 = no depth)."""

    t: float
    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """The pinhole model shared by the colour and the aligned depth image."""
        h, w = self.depth_m.shape
        return CameraIntrinsics(w, h, self.fx, self.fy, self.cx, self.cy)


VO_STATUSES = ("ok", "keyframe", "lost")


@dataclass(frozen=True)
class VoMeasurement:
    """Visual odometry output in base_link terms.

    status "ok": the base moved by (rotation, translation) from t_ref (a keyframe) to t — the pose
    of base_link at t expressed in base_link at t_ref — with covariance (6×6, order: translation m,
    rotation rad as a right perturbation of `rotation`). `new_keyframe` says that the frame at t is
    the reference of the next measurements. status "keyframe": a new reference at t, no motion.
    status "lost": no usable motion at t (`reason` says why); motion restarts at the next keyframe.
    Map keyframes (loop closure on floor seen before): `map_slot` ≥ 0 on a new keyframe stores it in
    that slot of the map too; `revisit_slot` ≥ 0 on an "ok" measurement says t_ref is that slot's
    keyframe, seen again now, not the current one.
    """

    t: float
    t_ref: float
    status: str
    rotation: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    translation: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    covariance: NDArray[np.float64] = field(default_factory=lambda: np.eye(6))
    inliers: int = 0
    new_keyframe: bool = False
    reason: str = ""
    map_slot: int = -1
    revisit_slot: int = -1


@dataclass(frozen=True)
class VoHealth:
    """VO as `status` and the run log show it (at host time t)."""

    t: float
    state: str  # "starting" (no frame yet), "tracking", "lost"
    frames: int
    dropped: int  # frames dropped from the queue because VO fell behind
    lost_frames: int
    measurements: int
    features: int  # corners of the current keyframe (0 when lost)
    tracked: int  # of those, tracked into the last frame
    inlier_ratio: float  # PnP inliers / tracked, last frame
    rate_hz: float
    latency_ms_median: float
    latency_ms_max: float
    cpu_s: float  # the VO thread's CPU time
    last_failure: str
    map_keyframes: int = 0  # keyframes kept to be found again (fusion.vo_map)
    revisit_attempts: int = 0
    revisits: int = 0  # attempts that found their map keyframe again


@dataclass(frozen=True)
class WheelEncoders:
    """Wheel encoder readings: counts (int64, unwrapped past the 32-bit wrap) and speeds (rad/s).

    `speed_spread_s`: how far apart the three speed requests left (0 in logs from before it existed).
    `speed_offsets_s`: when each speed request left, relative to t (the last of them; None in older
    logs, whose t is the requests' mean). On a busy loop the three leave up to hundreds of ms apart,
    and taken as one instant while the wheels speed up or stop their mixture reads as a motion the
    base did not make (a phantom 4 cm/s sideways put the fused pose 16 cm off in 3 s; issue 14).
    """

    t: float
    counts: NDArray[np.int64]
    speeds: NDArray[np.float64]
    speed_spread_s: float = 0.0
    speed_offsets_s: NDArray[np.float64] | None = None

    def wheel_speeds(self) -> WheelSpeeds:
        """The measured speeds as the WheelSpeeds message that wheel odometry consumes."""
        offsets = None if self.speed_offsets_s is None else self.speed_offsets_s.copy()
        return WheelSpeeds(t=self.t, speeds=self.speeds.copy(), sample_offsets_s=offsets)



@dataclass(frozen=True)
class RawRgbdFrame:
    """One RGB-D frame as the camera gives it: colour BGR uint8 (h, w, 3), depth uint16 (h, w) registered
    to the colour image (metres = depth * depth_scale, 0 = no depth), the colour camera's pinhole
    intrinsics (pixels). `RgbdFrame` is its metric form (depth float32 m)."""

    t: float
    number: int
    color: NDArray[np.uint8]
    depth: NDArray[np.uint16]
    depth_scale: float
    fx: float
    fy: float
    cx: float
    cy: float




@dataclass(frozen=True)
class SurveyEvent:
    """A survey control event on the monotonic clock: kind "line_start" | "line_end" | "survey_start" |
    "survey_end" | "abort"; `line` is the survey line index (-1 for survey-wide events)."""

    t: float
    kind: str
    line: int = -1


@dataclass(frozen=True)
class FusionSnapshot:
    """The filter at host time t: numbers (npz bytes), scalars, the reorder buffer and the not-yet-filtered."""

    t: float
    arrays: bytes
    scalars: dict[str, float] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)
    heap: list[list[Any]] = field(default_factory=list)  # [key, priority, seq, encoded message]
    queued: list[bytes] = field(default_factory=list)  # submitted to the fusion task, not yet pushed

@dataclass(frozen=True)
class GprStreamSetup:
    """A GPR data-socket connection begins: the setup its bytes follow (`new_epoch`: the NIC numbers from 1)."""

    t: float
    session: int
    points_per_trace: int
    stacks: int
    dt_ns: float
    t0_ns: float
    new_epoch: bool


@dataclass(frozen=True)
class GprRawChunk:
    """Bytes as read from the GPR data socket of connection `session`, at host receive time t."""

    t: float
    session: int
    data: bytes


Rate = float | str  # Hz, or the config key path that sets it (e.g. "survey.trace_rate_hz")


@dataclass(frozen=True)
class MessageSpec:
    """One registered type: logged (always, never, or as a config flag says), who publishes it at what rate.

    `streams` pairs each health name that publishes this type (a driver's stream, as `status` shows it)
    with its expected rate; event-driven types have none."""

    cls: type[Any]
    logged: bool | str  # True, False, or the config key (e.g. "realsense.record_frames") that decides
    streams: tuple[tuple[str, Rate], ...] = ()

    def is_logged(self, cfg: object) -> bool:
        """Whether the daemon appends this type to the run log under `cfg`."""
        return self.logged if isinstance(self.logged, bool) else bool(_lookup(cfg, self.logged))

    def expected_hz(self, cfg: object) -> float | None:
        """The expected rate of this type under `cfg`, all its streams together (None: event-driven)."""
        if not self.streams:
            return None
        return sum(_rate(rate, cfg) for _, rate in self.streams)


def _lookup(cfg: object, key: str) -> Any:
    return reduce(getattr, key.split("."), cfg)


def _rate(rate: Rate, cfg: object) -> float:
    return float(rate if isinstance(rate, float) else _lookup(cfg, rate))


REGISTRY: dict[str, MessageSpec] = {spec.cls.__name__: spec for spec in (
    MessageSpec(Trace, True, (("gpr", "survey.trace_rate_hz"),)),
    # The driver's raw stream (raw_sink): not in the daemon's run log yet — a log opens mid-stream, and
    # re-parsing it to the bit needs the parser's, counter's and clock's state at that moment as well.
    MessageSpec(GprRawChunk, False),
    MessageSpec(GprStreamSetup, False),
    MessageSpec(ImuSample, True, (("realsense.gyro", "realsense.gyro_hz"), ("realsense.accel", "realsense.accel_hz"))),
    MessageSpec(RawRgbdFrame, "realsense.record_frames", (("realsense.depth", "realsense.fps"),
                                                          ("realsense.color", "realsense.fps"))),
    MessageSpec(WheelEncoders, True, (("motors", "motors.poll_rate_hz"),)),
    MessageSpec(WheelSpeeds, True),  # commands, only while the wheels are driven
    MessageSpec(RgbdFrame, False),  # the metric form of RawRgbdFrame, made again on replay
    MessageSpec(VoMeasurement, True, (("vo", "realsense.fps"),)),
    MessageSpec(VoHealth, True, (("vo.health", 1.0),)),
    MessageSpec(Pose, False, (("fusion", "fusion.output_rate_hz"),)),  # replay recomputes them
    MessageSpec(FusionSnapshot, True),  # one as a run log opens
    MessageSpec(SurveyEvent, True),
)}
MESSAGE_TYPES: dict[str, type[Any]] = {name: spec.cls for name, spec in REGISTRY.items()}


def expected_rates(cfg: object) -> dict[str, float]:
    """Every publishing stream's expected rate (Hz) under `cfg`, by its health name."""
    return {name: _rate(rate, cfg) for spec in REGISTRY.values() for name, rate in spec.streams}


def _pack_value(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return {"__nd__": [value.dtype.str, list(value.shape), value.tobytes()]}
    return value


def _unpack_value(value: Any) -> Any:
    if isinstance(value, dict) and "__nd__" in value:
        dtype, shape, raw = value["__nd__"]
        return np.frombuffer(raw, dtype=np.dtype(dtype)).reshape(shape).copy()
    return value


def encode(message: Any) -> bytes:
    """Serialise a registered message dataclass to msgpack bytes."""
    name = type(message).__name__
    if name not in MESSAGE_TYPES:
        raise ProtocolError(f"cannot encode {name}: not a registered message type")
    body = {f.name: _pack_value(getattr(message, f.name)) for f in dataclasses.fields(message)}
    return msgpack.packb([name, body], use_bin_type=True)  # type: ignore[no-any-return]


def decode(data: bytes) -> Any:
    """Parse msgpack bytes produced by `encode` back into the message dataclass."""
    try:
        name, body = msgpack.unpackb(data, raw=False)
        cls = MESSAGE_TYPES[name]
        return cls(**{k: _unpack_value(v) for k, v in body.items()})
    except (ValueError, TypeError, KeyError, msgpack.UnpackException) as exc:
        raise ProtocolError(f"corrupt message record ({exc}); the record is skipped") from exc
