"""Simulated D435i IMU (Bosch BMI055): gyro and accelerometer streams with white noise, bias and LSBs.

Figures (per axis), and where they come from:
- gyro noise density 0.014 °/s/√Hz = 2.44e-4 rad/s/√Hz — BMI055 data sheet (BST-BMI055-DS000-08);
- accel noise density 150 µg/√Hz = 1.47e-3 m/s²/√Hz — BMI055 data sheet (normal mode);
- bias random walk: the data sheet gives none; gyro 2e-5 rad/s²/√Hz is the D435i value in ORB-SLAM3's
  RealSense config, accel 2e-4 m/s³/√Hz is ~3× a Kalibr Allan fit of a D435i (VINS-Mono issue #472),
  margin for temperature;
- turn-on bias σ 0.2 °/s and 0.05 m/s²: what is left after `rs-imu-calibration` (the data sheet's
  uncalibrated offsets are ±1 °/s and ±70 mg);
- LSBs: gyro ±1000 °/s over 16 bits, accel ±4 g over 12 bits (the D435i's default ranges);
- rates: gyro 400 Hz, accel 250 Hz, each its own message stream (as librealsense delivers them).
Samples are expressed in base_link: the driver rotates the D435i's IMU axes once, so does the sim.
Discrete white noise has σ = density · √rate; the bias walks by K · √dt per sample (Kalibr's model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.messages import ImuSample
from gprbot.sim.motion_truth import GroundTruth

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ImuModel:
    """Noise, bias and sampling of one simulated IMU."""

    gyro_rate_hz: float = 400.0
    accel_rate_hz: float = 250.0
    gyro_noise_density: float = 2.44e-4  # rad/s/√Hz
    accel_noise_density: float = 1.47e-3  # m/s²/√Hz
    gyro_bias_walk: float = 2.0e-5  # rad/s²/√Hz
    accel_bias_walk: float = 2.0e-4  # m/s³/√Hz
    gyro_turn_on_bias_std: float = math.radians(0.2)  # rad/s
    accel_turn_on_bias_std: float = 0.05  # m/s²
    gyro_lsb: float = math.radians(2000.0 / 65536.0)  # rad/s
    accel_lsb: float = 8.0 * 9.80665 / 4096.0  # m/s²


@dataclass(frozen=True)
class ImuRecording:
    """A simulated IMU run: both streams, and the true biases behind them (for tests and evaluation)."""

    gyro_t: FloatArray
    gyro: FloatArray
    gyro_bias: FloatArray
    accel_t: FloatArray
    accel: FloatArray
    accel_bias: FloatArray

    def messages(self) -> list[ImuSample]:
        """Gyro-only and accel-only ImuSample messages, merged in time order."""
        gyro = [ImuSample(float(t), gyro=g) for t, g in zip(self.gyro_t, self.gyro, strict=True)]
        accel = [ImuSample(float(t), accel=a) for t, a in zip(self.accel_t, self.accel, strict=True)]
        return sorted(gyro + accel, key=lambda m: m.t)


def _stream(
    rng: np.random.Generator,
    truth: FloatArray,
    rate_hz: float,
    density: float,
    walk: float,
    turn_on_std: float,
    lsb: float,
    constant_bias: FloatArray | None,
) -> tuple[FloatArray, FloatArray]:
    n = truth.shape[0]
    start = constant_bias if constant_bias is not None else rng.normal(0.0, turn_on_std, 3)
    steps = rng.normal(0.0, walk / math.sqrt(rate_hz), (n, 3))
    steps[0] = 0.0
    bias = start + np.cumsum(steps, axis=0)
    measured = truth + bias + rng.normal(0.0, density * math.sqrt(rate_hz), (n, 3))
    if lsb > 0.0:
        measured = np.round(measured / lsb) * lsb
    return measured, bias


def simulate_imu(
    truth: GroundTruth,
    model: ImuModel | None = None,
    seed: int = 0,
    gyro_bias: FloatArray | None = None,
    accel_bias: FloatArray | None = None,
) -> ImuRecording:
    """Sample both IMU streams over the whole trajectory; a given bias replaces the random turn-on bias."""
    model = model or ImuModel()
    rng = np.random.default_rng(seed + 104729)
    gyro_t = np.arange(truth.t_start, truth.t_end, 1.0 / model.gyro_rate_hz)
    accel_t = np.arange(truth.t_start, truth.t_end, 1.0 / model.accel_rate_hz)
    gyro, gb = _stream(
        rng, truth.angular_velocity(gyro_t), model.gyro_rate_hz, model.gyro_noise_density, model.gyro_bias_walk,
        model.gyro_turn_on_bias_std, model.gyro_lsb, gyro_bias,
    )
    accel, ab = _stream(
        rng, truth.specific_force(accel_t), model.accel_rate_hz, model.accel_noise_density, model.accel_bias_walk,
        model.accel_turn_on_bias_std, model.accel_lsb, accel_bias,
    )
    return ImuRecording(gyro_t, gyro, gb, accel_t, accel, ab)


def allan_deviation(samples: FloatArray, rate_hz: float, taus_s: FloatArray) -> FloatArray:
    """Overlapping Allan deviation of a 1-D rate signal at averaging times taus_s (IEEE Std 952)."""
    theta = np.concatenate([[0.0], np.cumsum(samples)]) / rate_hz
    out = np.empty(len(taus_s))
    for i, tau in enumerate(taus_s):
        m = round(tau * rate_hz)
        d = theta[2 * m:] - 2.0 * theta[m:-m] + theta[: -2 * m]
        out[i] = math.sqrt(float(np.mean(d**2)) / (2.0 * (m / rate_hz) ** 2))
    return out
