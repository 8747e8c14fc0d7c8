"""Message types that cross module boundaries, and their msgpack codec.

Every message carries `t`: seconds on the host monotonic clock (drivers convert device clocks once).
Arrays travel as (dtype, shape, raw bytes) so that a run log replays bit for bit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
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
    """Commanded or measured wheel angular speeds (rad/s), one per omni wheel."""

    t: float
    speeds: NDArray[np.float64]


MESSAGE_TYPES: dict[str, type[Any]] = {
    cls.__name__: cls for cls in (Trace, Pose, ImuSample, WheelSpeeds)
}


def register_message(cls: type[Any]) -> type[Any]:
    """Add a dataclass to the codec's table (drivers and modules may define their own messages)."""
    MESSAGE_TYPES[cls.__name__] = cls
    return cls


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
