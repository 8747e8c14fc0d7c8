"""Simulated wheel encoders of the kiwi base: unequal wheel radii, slip, count quantisation, 50 Hz.

Each wheel's rim must move with the ground under it (the kiwi matrix of the true body twist); the
wheel turns that distance over its *true* radius r·(1 + ε_i), ε_i ~ U(±1.5 %), and spins a little
faster or slower than that: a slowly wandering slip (σ 0.3 %, 2 s correlation), slip proportional to
the drive torque (2 % per m/s² of rim acceleration) and rare slip events (a wheel loses grip for
0.3 s, +8 %). The encoder counts the wheel angle (counts_per_rev) and the controller reports the
speed as counts differenced over each 20 ms poll, as a RoboClaw speed read would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from gprbot.config import MotorsConfig
from gprbot.messages import WheelSpeeds
from gprbot.motion.kinematics import kiwi_matrix
from gprbot.sim.motion_truth import GroundTruth

FloatArray = NDArray[np.float64]
_FINE_HZ = 1000.0


@dataclass(frozen=True)
class EncoderModel:
    """Wheel and encoder imperfections."""

    rate_hz: float = 50.0
    radius_error_max: float = 0.015
    slip_std: float = 0.003
    slip_correlation_s: float = 2.0
    slip_per_rim_accel: float = 0.02  # per m/s²
    slip_event_rate_hz: float = 1.0 / 30.0
    slip_event_fraction: float = 0.08
    slip_event_duration_s: float = 0.3


@dataclass(frozen=True)
class EncoderRecording:
    """Measured wheel speeds (rad/s) at the poll times, and the true radius scale of each wheel."""

    t: FloatArray
    speeds: FloatArray
    radius_scale: FloatArray

    def messages(self) -> list[WheelSpeeds]:
        """WheelSpeeds messages in time order."""
        return [WheelSpeeds(float(t), s) for t, s in zip(self.t, self.speeds, strict=True)]


def _slip(rng: np.random.Generator, t: FloatArray, rim_accel: FloatArray, rim: FloatArray,
          model: EncoderModel) -> FloatArray:
    """Slip fraction (n, 3): positive means the wheel turns faster than the ground under it."""
    n = t.size
    alpha = math.exp(-1.0 / (_FINE_HZ * model.slip_correlation_s))
    drive = rng.normal(0.0, model.slip_std * math.sqrt(1.0 - alpha**2), (n, 3))
    wander = lfilter([1.0], [1.0, -alpha], drive, axis=0)
    torque = model.slip_per_rim_accel * rim_accel * np.sign(rim)
    events = np.zeros((n, 3))
    count = rng.poisson(model.slip_event_rate_hz * (t[-1] - t[0]))
    for start in rng.uniform(t[0], t[-1], count):
        events[(t >= start) & (t < start + model.slip_event_duration_s), rng.integers(3)] += model.slip_event_fraction
    moving = np.abs(rim) > 1e-4  # a parked wheel does not slip
    return np.asarray((wander + torque + events) * moving)


def simulate_encoders(
    truth: GroundTruth,
    motors: MotorsConfig | None = None,
    model: EncoderModel | None = None,
    seed: int = 0,
    radius_scale: FloatArray | None = None,
    ideal: bool = False,
) -> EncoderRecording:
    """Wheel speed reports over the trajectory; `ideal` turns slip and radius errors off (not quantisation)."""
    motors = motors or MotorsConfig()
    model = model or EncoderModel()
    rng = np.random.default_rng(seed + 15485863)
    if radius_scale is None:
        radius_scale = np.ones(3) if ideal else 1.0 + rng.uniform(-model.radius_error_max, model.radius_error_max, 3)
    t = np.arange(truth.t_start, truth.t_end, 1.0 / _FINE_HZ)
    body = truth.body_velocity(t)
    twist = np.column_stack([body[:, 0], body[:, 1], truth.angular_velocity(t)[:, 2]])
    rim = twist @ kiwi_matrix(motors.base_radius_m).T
    slip = np.zeros_like(rim) if ideal else _slip(rng, t, np.gradient(rim, t, axis=0), rim, model)
    wheel_rate = rim / (motors.wheel_radius_m * radius_scale) * (1.0 + slip)
    angle = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (wheel_rate[1:] + wheel_rate[:-1]), axis=0) / _FINE_HZ])
    step = round(_FINE_HZ / model.rate_hz)
    counts_per_rad = motors.encoder_counts_per_rev / (2.0 * math.pi)
    counts = np.floor(angle[::step] * counts_per_rad)
    poll_t = t[::step]
    speeds = np.diff(counts, axis=0) / counts_per_rad / np.diff(poll_t)[:, None]
    return EncoderRecording(poll_t[1:], speeds, np.asarray(radius_scale, dtype=np.float64))
