"""The pose filter's whole state as a run-log record, so a replay continues the daemon's filter to the bit.

The daemon's filter runs from the daemon's start, long before a run log opens; re-initialising it
from the log would give other poses. So the log's first record after its header is a
`FusionSnapshot`: the EKF's nominal state and covariance, the reorder buffer's queued messages (with
their sort keys and sequence numbers), the initialisation sums and counters, and the messages already
submitted but not yet filtered. Replaying then means: restore, push those queued messages, then push
every logged filter input in log order (the order the fusion task got them). Numbers are stored as
float64 bytes (npz, no pickle: a log from elsewhere cannot run code), messages with the message codec.
"""

from __future__ import annotations

import dataclasses
import io
import math
import zipfile
from collections.abc import Iterable
from typing import Any

import numpy as np

from gprbot.config import FusionConfig, MotorsConfig
from gprbot.errors import GprbotError
from gprbot.fusion.fuser import FusionStats, PoseFuser, SensorMessage
from gprbot.messages import FusionSnapshot, decode, encode

_EKF_ARRAYS = ("p", "v", "R", "gyro_bias", "accel_bias", "wheel_scale", "clone_p", "clone_R", "gyro", "accel",
               "_sum_gyro", "_sum_accel")
_SLOT_ARRAYS = ("slot_p", "slot_R", "slot_t")  # map keyframe clones (absent from snapshots before them)
_EKF_SCALARS = ("t", "clone_t", "floor_z", "_held_since")
_FUSER_SCALARS = ("_newest", "_newest_gyro", "_newest_accel", "_newest_wheel", "_released", "_init_start",
                  "_next_tick")


def take_snapshot(t: float, fuser: PoseFuser, queued: Iterable[SensorMessage] = ()) -> FusionSnapshot:
    """Everything `restore` needs to continue `fuser` exactly as it would have gone on."""
    ekf = fuser.ekf
    arrays = {name: np.asarray(getattr(ekf, name), dtype=np.float64) for name in _EKF_ARRAYS + _SLOT_ARRAYS}
    arrays["kf_x"], arrays["kf_P"] = np.asarray(ekf.kf.x, dtype=np.float64), np.asarray(ekf.kf.P, dtype=np.float64)
    arrays["init_gyro"] = np.array(fuser._init_gyro, dtype=np.float64).reshape(-1, 3)
    arrays["init_accel"] = np.array(fuser._init_accel, dtype=np.float64).reshape(-1, 3)
    arrays.update(ekf.velocity_changes.arrays())
    # Where the filter puts the base when it initialises (a snapshot taken before that, as at a run log's
    # start on a daemon just started, would otherwise restore to the origin: every pose a lever arm off).
    position, yaw = fuser._initial
    arrays["initial_pose"] = np.append(np.asarray(position, dtype=np.float64), yaw)
    buffer = io.BytesIO()
    np.savez(buffer, allow_pickle=False, **arrays)
    scalars = {f"ekf.{name}": float(getattr(ekf, name)) for name in _EKF_SCALARS}
    scalars.update({f"fuser.{name}": float(getattr(fuser, name)) for name in _FUSER_SCALARS})
    counters = {f"stats.{k}": int(v) for k, v in dataclasses.asdict(fuser.stats).items()}
    counters.update({f"rejected.{k}": int(v) for k, v in ekf.rejected_in_a_row.items()})
    heap = [[key, priority, seq, encode(message)] for key, priority, seq, message in fuser._heap]
    counters["fuser.next_seq"] = fuser._next_seq
    return FusionSnapshot(t, buffer.getvalue(), scalars, counters, heap, [encode(m) for m in queued])


def restore(snapshot: FusionSnapshot, config: FusionConfig, motors: MotorsConfig,
            initial_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[PoseFuser, list[Any]]:
    """A filter in the snapshot's state, and the messages that were waiting to be pushed into it.

    `initial_pose` (x, y, yaw of the base) is where a filter not yet initialised will start, for snapshots
    that predate `initial_pose` in their arrays: the daemon's start pose, `survey.start_pose(config)`.
    """
    x, y, yaw = initial_pose
    fuser = PoseFuser(config, motors, initial_position=(x, y, 0.0), initial_yaw_rad=yaw)
    ekf = fuser.ekf
    try:
        with np.load(io.BytesIO(snapshot.arrays), allow_pickle=False) as data:
            arrays = {name: np.array(data[name]) for name in data.files}
        if "initial_pose" in arrays:
            fuser._initial = (arrays["initial_pose"][:3].copy(), float(arrays["initial_pose"][3]))
        for name in _EKF_ARRAYS:
            setattr(ekf, name, arrays[name])
        dim = arrays["kf_P"].shape[0]
        if dim != ekf.dim:
            raise ValueError(f"its filter has {(dim - 24) // 6} map keyframe slots, the config "
                             f"{ekf.slots} (fusion.vo_map_slots)")
        for name in _SLOT_ARRAYS:
            if name in arrays:
                setattr(ekf, name, arrays[name])
        ekf.kf.x, ekf.kf.P = arrays["kf_x"], arrays["kf_P"]
        fuser._init_gyro = list(arrays["init_gyro"])
        fuser._init_accel = list(arrays["init_accel"])
        ekf.velocity_changes.load(arrays)
        # What a snapshot written before a field existed restores it to: its behaviour then (no wheel
        # wait; one newest-IMU time for both streams).
        imu = snapshot.scalars.get("fuser._newest_imu", -math.inf)
        scalars = {"fuser._newest_wheel": -math.inf, "fuser._newest_gyro": imu, "fuser._newest_accel": imu,
                   **snapshot.scalars}
        for name in _EKF_SCALARS:
            setattr(ekf, name, scalars[f"ekf.{name}"])
        for name in _FUSER_SCALARS:
            setattr(fuser, name, scalars[f"fuser.{name}"])
        fuser.stats = FusionStats(**{k[6:]: v for k, v in snapshot.counters.items() if k.startswith("stats.")})
        ekf.rejected_in_a_row = {k[9:]: v for k, v in snapshot.counters.items() if k.startswith("rejected.")}
        fuser._heap = [(float(key), int(priority), int(seq), decode(raw)) for key, priority, seq, raw in snapshot.heap]
        fuser._next_seq = int(snapshot.counters["fuser.next_seq"])
        queued = [decode(raw) for raw in snapshot.queued]
    except (KeyError, ValueError, TypeError, OSError, zipfile.BadZipFile) as exc:
        raise GprbotError(f"the run log's fusion snapshot is unreadable ({exc}); replay re-runs the filter "
                          "from the log's start instead") from exc
    return fuser, queued

