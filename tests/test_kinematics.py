"""Kiwi kinematics against hand-computed values and an independent contact-point geometry model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gprbot.config import MotorsConfig
from gprbot.errors import ConfigError
from gprbot.messages import WheelSpeeds
from gprbot.motion.kinematics import (
    KiwiKinematics,
    WheelOdometry,
    integrate_body_twist,
    limit_wheel_acceleration,
    saturate_wheel_speeds,
    wrap_angle,
)

R, D = 0.05, 0.15
KIN = KiwiKinematics(wheel_radius_m=R, base_radius_m=D)
speeds = st.floats(-1.0, 1.0, allow_nan=False)
rates = st.floats(-3.0, 3.0, allow_nan=False)


def rim_speeds_from_geometry(twist: np.ndarray, d: float) -> np.ndarray:
    """Independent model: wheel i sits at bearing θ_i + 90°, drives along θ_i; rim speed = u·(v + ω×p)."""
    vx, vy, omega = twist
    out = []
    for theta in (0.0, 2 * math.pi / 3, -2 * math.pi / 3):
        u = np.array([math.cos(theta), math.sin(theta)])
        p = d * np.array([math.cos(theta + math.pi / 2), math.sin(theta + math.pi / 2)])
        contact_velocity = np.array([vx - omega * p[1], vy + omega * p[0]])
        out.append(float(u @ contact_velocity))
    return np.array(out)


def test_pure_forward_matches_hand_computed_wheel_speeds() -> None:
    # vx = 0.1 m/s: wheel 0 rim 0.1, wheels 1 and 2 rim 0.1·cos(±120°) = −0.05; divided by r = 0.05.
    np.testing.assert_allclose(KIN.wheel_speeds((0.1, 0.0, 0.0)), [2.0, -1.0, -1.0], atol=1e-12)


def test_pure_sideways_matches_hand_computed_wheel_speeds() -> None:
    # vy = 0.1 m/s: rims 0, 0.1·sin(120°), 0.1·sin(−120°) = 0, ±0.0866; over r: 0, ±√3.
    expected = [0.0, math.sqrt(3), -math.sqrt(3)]
    np.testing.assert_allclose(KIN.wheel_speeds((0.0, 0.1, 0.0)), expected, atol=1e-12)


def test_ccw_rotation_spins_every_wheel_negative() -> None:
    np.testing.assert_allclose(KIN.wheel_speeds((0.0, 0.0, 1.0)), [-D / R] * 3, atol=1e-12)


@given(speeds, speeds, rates)
def test_matrix_sign_convention_matches_contact_geometry(vx: float, vy: float, omega: float) -> None:
    twist = np.array([vx, vy, omega])
    np.testing.assert_allclose(KIN.wheel_speeds(twist) * R, rim_speeds_from_geometry(twist, D), atol=1e-12)


@given(speeds, speeds, rates)
def test_inverse_then_forward_round_trip(vx: float, vy: float, omega: float) -> None:
    twist = np.array([vx, vy, omega])
    np.testing.assert_allclose(KIN.body_twist(KIN.wheel_speeds(twist)), twist, atol=1e-12)


@given(rates, rates, rates)
def test_forward_then_inverse_round_trip(w0: float, w1: float, w2: float) -> None:
    wheels = np.array([w0, w1, w2])
    np.testing.assert_allclose(KIN.wheel_speeds(KIN.body_twist(wheels)), wheels, atol=1e-12)


def test_from_config_uses_motor_geometry_and_rejects_bad_radius() -> None:
    kin = KiwiKinematics.from_config(MotorsConfig(wheel_radius_m=0.1, base_radius_m=0.2))
    np.testing.assert_allclose(kin.wheel_speeds((0.0, 0.0, 1.0)), [-2.0, -2.0, -2.0])
    with pytest.raises(ConfigError, match=r"motors\.wheel_radius_m"):
        KiwiKinematics(wheel_radius_m=0.0, base_radius_m=0.15)
    with pytest.raises(ValueError, match="expected 3 numbers"):
        KIN.wheel_speeds((0.1, 0.2))


@pytest.mark.parametrize("twist", [(1.5, 0.7, 0.0), (-0.4, 1.9, 0.0), (1.2, -1.1, 0.8)])
def test_saturation_keeps_direction_and_respects_max(twist: tuple[float, float, float]) -> None:
    wheels = KIN.wheel_speeds(twist)
    assert np.max(np.abs(wheels)) > 20.0  # the case must actually saturate
    limited = saturate_wheel_speeds(wheels, 20.0)
    assert np.max(np.abs(limited)) == pytest.approx(20.0)
    result = KIN.body_twist(limited)
    assert math.atan2(result[1], result[0]) == pytest.approx(math.atan2(twist[1], twist[0]), abs=1e-12)
    np.testing.assert_allclose(np.cross(result, twist), 0.0, atol=1e-12)  # same ratio vx : vy : ω
    assert float(result @ np.asarray(twist)) > 0.0


def test_saturation_leaves_feasible_speeds_alone() -> None:
    wheels = KIN.wheel_speeds((0.1, 0.05, 0.0))
    np.testing.assert_array_equal(saturate_wheel_speeds(wheels, 20.0), wheels)


def test_acceleration_limit_ramps_from_rest_along_the_commanded_direction() -> None:
    target = KIN.wheel_speeds((0.3, 0.2, 0.0))  # peak wheel |w| = 6 + ... rad/s
    peak = float(np.max(np.abs(target)))
    current = np.zeros(3)
    steps = 0
    while not np.allclose(current, target):
        following = limit_wheel_acceleration(target, current, 40.0, 0.01)
        assert np.max(np.abs(following - current)) <= 0.4 + 1e-12
        twist = KIN.body_twist(following)
        assert math.atan2(twist[1], twist[0]) == pytest.approx(math.atan2(0.2, 0.3), abs=1e-12)
        assert twist[2] == pytest.approx(0.0, abs=1e-12)
        current = following
        steps += 1
    assert steps == math.ceil(peak / 0.4)


def test_acceleration_limit_reaches_a_near_target_in_one_step() -> None:
    previous = np.array([1.0, -0.5, -0.5])
    target = np.array([1.1, -0.55, -0.55])
    np.testing.assert_array_equal(limit_wheel_acceleration(target, previous, 40.0, 0.01), target)


def test_integrate_straight_and_sideways_in_a_rotated_frame() -> None:
    facing_left = integrate_body_twist((1.0, 2.0, math.pi / 2), (0.5, 0.0, 0.0), 2.0)
    np.testing.assert_allclose(facing_left, [1.0, 3.0, math.pi / 2])
    sideways = integrate_body_twist((0.0, 0.0, 0.0), (0.0, 0.1, 0.0), 3.0)
    np.testing.assert_allclose(sideways, [0.0, 0.3, 0.0])


def test_integrate_quarter_circle_is_exact() -> None:
    # v = 1 m/s, ω = 1 rad/s: a circle of radius 1 centred at (0, 1); a quarter turn ends at (1, 1).
    quarter = integrate_body_twist((0.0, 0.0, 0.0), (1.0, 0.0, 1.0), math.pi / 2)
    np.testing.assert_allclose(quarter, [1.0, 1.0, math.pi / 2], atol=1e-12)


def test_wrap_angle_range() -> None:
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-3 * math.pi / 2) == pytest.approx(math.pi / 2)


def test_wheel_odometry_dead_reckons_a_boustrophedon_leg() -> None:
    odometry = WheelOdometry(KIN, initial_pose=(0.0, 0.0, 0.0))
    forward = KIN.wheel_speeds((0.1, 0.0, 0.0))
    sideways = KIN.wheel_speeds((0.0, 0.1, 0.0))
    for k in range(201):  # 2 s forward
        odometry.update(WheelSpeeds(t=k * 0.01, speeds=forward))
    np.testing.assert_allclose(odometry.pose, [0.2, 0.0, 0.0], atol=1e-12)
    odometry.update(WheelSpeeds(t=2.0, speeds=sideways))  # repeated stamp: ignored
    for k in range(1, 101):  # then 1 s sideways (the first interval averages the two twists)
        odometry.update(WheelSpeeds(t=2.0 + k * 0.01, speeds=sideways))
    np.testing.assert_allclose(odometry.pose, [0.2005, 0.0995, 0.0], atol=1e-12)
    message = odometry.pose_message()
    assert message.t == pytest.approx(3.0)
    np.testing.assert_allclose(message.orientation, [0.0, 0.0, 0.0, 1.0])
