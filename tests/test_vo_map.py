"""Map keyframes: floor seen again on the next line, measured against its stored pose in the filter."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from gprbot.config import FusionConfig, MotorsConfig
from gprbot.errors import ConfigError, GprbotError
from gprbot.fusion.baselines import vo_only
from gprbot.fusion.ekf import DIM, ErrorStateEkf
from gprbot.fusion.fuser import PoseFuser
from gprbot.fusion.snapshot import restore, take_snapshot
from gprbot.fusion.so3 import log_so3, matrix_to_quat, quat_to_matrix, yaw_of
from gprbot.fusion.vo import RgbdOdometry
from gprbot.fusion.vo_geometry import VoConfig, detect_keyframe, warped_toward
from gprbot.fusion.vo_map import MapConfig
from gprbot.messages import ImuSample, VoMeasurement, decode, encode
from gprbot.motion.kinematics import KiwiKinematics
from gprbot.sim.camera import FloorCamera
from gprbot.sim.floor_texture import FloorSpec

FPS = 30.0


def there_and_back(length_m: float = 0.5, step_m: float = 0.1, speed: float = 0.1) -> list[tuple[float, np.ndarray]]:
    """Base positions at the camera rate: a line along +x, a step along +y, the line back along −x."""
    legs = [np.array([length_m, 0.0]), np.array([0.0, step_m]), np.array([-length_m, 0.0])]
    p, t, out = np.array([0.2, 0.0]), 0.0, []
    for leg in legs:
        n = round(float(np.linalg.norm(leg)) / speed * FPS)
        for i in range(n):
            out.append((t, np.array([*(p + leg * i / n), 0.0])))
            t += 1.0 / FPS
        p = p + leg
    return out


@pytest.fixture(scope="module")
def drive() -> tuple[list[VoMeasurement], dict[float, np.ndarray]]:
    camera = FloorCamera(FloorSpec(size_px=(1536, 1536), smooth_patches_m=()), seed=4)
    vo = RgbdOdometry(camera.model.mount, map_config=MapConfig(min_age_s=3.0))
    path = there_and_back()
    measurements = [m for t, p in path for m in vo.process(camera.render(t, np.eye(3), p))]
    assert len(vo.map.entries) >= 3 and vo.map.found >= 3 and vo.map.attempts >= vo.map.found  # what `status` shows
    return measurements, dict(path)


def test_the_line_driven_back_finds_the_first_lines_keyframes_again(
        drive: tuple[list[VoMeasurement], dict[float, np.ndarray]]) -> None:
    measurements, truth = drive
    stored = {(m.map_slot, m.t) for m in measurements if m.new_keyframe and m.map_slot >= 0}
    revisits = [m for m in measurements if m.revisit_slot >= 0]
    assert len(stored) >= 3 and len(revisits) >= 3
    for m in revisits:
        assert (m.revisit_slot, m.t_ref) in stored  # measured from a keyframe the filter was told to keep
        assert m.t - m.t_ref >= 3.0
        expected = truth[m.t] - truth[m.t_ref]  # the robot never turned
        assert abs(expected[1]) > 0.05  # from the other line, not the chain it was on
        turn = log_so3(quat_to_matrix(m.rotation))
        assert np.linalg.norm(m.translation - expected) < 0.002 and abs(math.degrees(turn[2])) < 0.1
        error = np.concatenate([m.translation - expected, turn])
        assert np.all(np.abs(error) < 4.0 * np.sqrt(np.diag(m.covariance)))  # and it knows how good it is
        back = decode(encode(m))
        assert (back.revisit_slot, back.map_slot) == (m.revisit_slot, m.map_slot)


def test_no_map_keyframes_when_the_map_has_no_slots() -> None:
    camera = FloorCamera(FloorSpec(size_px=(1536, 1536), smooth_patches_m=()), seed=4)
    vo = RgbdOdometry(camera.model.mount, map_config=MapConfig(slots=0, min_age_s=3.0))
    measurements = [m for t, p in there_and_back() for m in vo.process(camera.render(t, np.eye(3), p))]
    assert all(m.map_slot == -1 and m.revisit_slot == -1 for m in measurements)


def ready_ekf(slots: int = 4) -> ErrorStateEkf:
    ekf = ErrorStateEkf(FusionConfig(vo_map_slots=slots), KiwiKinematics.from_config(MotorsConfig()))
    ekf.initialize(0.0, np.array([0.0, 0.0, 9.80665]), np.zeros(3), np.zeros(3), 0.0)
    return ekf


def drift(ekf: ErrorStateEkf, seconds: float, gyro_z: float) -> None:
    """The robot stands still while the gyro reads an unmodelled rate: the yaw drifts, its σ grows."""
    t = ekf.t
    for _ in range(int(seconds * 100)):
        t += 0.01
        ekf.add_imu(t, np.array([0.0, 0.0, gyro_z]), np.array([0.0, 0.0, 9.80665]))


def test_a_revisit_pulls_a_drifted_heading_back_to_the_stored_keyframes() -> None:
    ekf = ready_ekf()
    assert ekf.store_in_slot(2)
    kept_t = ekf.t
    drift(ekf, 20.0, math.radians(0.01))  # 0.2° of heading lost
    assert math.degrees(yaw_of(ekf.R)) == pytest.approx(0.2, abs=0.01)
    yaw_std_before = ekf.horizontal_std()[1]
    seen_again = VoMeasurement(ekf.t, kept_t, "ok", matrix_to_quat(np.eye(3)), np.zeros(3),
                               np.diag([1e-8] * 3 + [1e-8] * 3), 100, revisit_slot=2)
    assert ekf.update_vo(seen_again) == "applied"
    assert abs(math.degrees(yaw_of(ekf.R))) < 0.01
    assert ekf.horizontal_std()[1] < 0.5 * yaw_std_before
    # a slot never stored, one beyond the filter's, and a stale reference time are not measurements
    for slot, t_ref in ((0, kept_t), (9, kept_t), (2, kept_t + 1.0)):
        stale = VoMeasurement(ekf.t, t_ref, "ok", matrix_to_quat(np.eye(3)), np.zeros(3), np.eye(6) * 1e-8,
                              100, revisit_slot=slot)
        assert ekf.update_vo(stale) == "skipped"


def test_the_written_out_update_is_filterpys_joseph_form() -> None:
    rng = np.random.default_rng(7)
    ekf = ready_ekf(slots=2)
    A = rng.normal(size=(ekf.dim, ekf.dim))
    ekf.kf.P = A @ A.T / ekf.dim + np.eye(ekf.dim) * 1e-3
    H, R = rng.normal(size=(4, ekf.dim)), np.diag(rng.uniform(0.5, 2.0, 4))
    residual = rng.normal(size=4) * 0.01
    reference = KalmanFilter(dim_x=ekf.dim, dim_z=4)
    reference.P, reference.x = ekf.kf.P.copy(), np.zeros((ekf.dim, 1))
    reference.update(residual.reshape(-1, 1), R=R, H=H)
    p_before = ekf.p.copy()
    assert ekf._update("wheels", residual, H, R)
    assert np.allclose(ekf.kf.P, reference.P, rtol=1e-9, atol=1e-12)
    assert np.allclose(ekf.p - p_before, reference.x.ravel()[:3], rtol=1e-9, atol=1e-15)


def test_a_snapshot_keeps_the_map_slots_and_refuses_another_slot_count() -> None:
    fuser = PoseFuser(FusionConfig(vo_map_slots=3))
    for i in range(80):
        fuser.push(ImuSample(0.01 * i, np.zeros(3), np.array([0.0, 0.0, 9.80665])))
    fuser.ekf.store_in_slot(1)
    back, _ = restore(decode(encode(take_snapshot(1.0, fuser))), FusionConfig(vo_map_slots=3), MotorsConfig())
    assert np.array_equal(back.ekf.slot_t, fuser.ekf.slot_t, equal_nan=True)
    assert np.array_equal(back.ekf.kf.P, fuser.ekf.kf.P) and np.array_equal(back.ekf.slot_R, fuser.ekf.slot_R)
    assert back.ekf.kf.P.shape == (DIM + 18, DIM + 18)
    with pytest.raises(GprbotError, match="vo_map_slots"):
        restore(take_snapshot(1.0, fuser), FusionConfig(vo_map_slots=5), MotorsConfig())


@pytest.mark.parametrize("slots", [-1, 2.5, 41])
def test_the_slot_count_must_be_a_small_whole_number(slots: object) -> None:
    with pytest.raises(ConfigError, match=r"fusion\.vo_map_slots"):
        FusionConfig(vo_map_slots=slots)  # type: ignore[arg-type]


def test_the_vo_only_baseline_chains_past_a_revisit_at_the_same_instant() -> None:
    """A revisit at a frame whose motion is then emitted again by a tracking loss: one pose per instant."""
    step = matrix_to_quat(np.eye(3))
    cov = np.eye(6) * 1e-8
    messages = [
        VoMeasurement(0.0, 0.0, "keyframe", new_keyframe=True, map_slot=0),
        VoMeasurement(0.5, 0.0, "ok", step, np.array([0.05, 0.0, 0.0]), cov, 100, True),
        VoMeasurement(9.8, 0.0, "ok", step, np.array([0.0, 0.1, 0.0]), cov, 100, revisit_slot=0),
        VoMeasurement(9.8, 0.5, "ok", step, np.array([0.05, 0.0, 0.0]), cov, 100, False),
        VoMeasurement(9.9, 9.9, "keyframe", new_keyframe=True),
    ]
    poses = vo_only(messages, np.zeros(3), 0.0, 0.0)
    times = [p.t for p in poses]
    assert times == sorted(set(times))
    assert poses[-2].position == pytest.approx([0.10, 0.0, 0.0])  # the chain's, not the revisit's


def test_a_keyframe_warped_by_the_predicted_motion_looks_like_the_frame_from_the_next_line() -> None:
    camera = FloorCamera(FloorSpec(size_px=(1536, 1536), smooth_patches_m=()), seed=4)
    start = np.array([0.4, 0.0, 0.0])
    first = camera.render(0.0, np.eye(3), start)
    second = camera.render(9.0, np.eye(3), start + np.array([0.0, 0.1, 0.0]))  # the next line
    vo = RgbdOdometry(camera.model.mount)
    keyframe = detect_keyframe(0.0, first.color[:, :, 0], first.depth_m, first.intrinsics, VoConfig())
    assert keyframe is not None
    rvec, tvec = vo._base_to_camera(np.eye(3), np.array([0.0, 0.1, 0.0]))
    warped = warped_toward(keyframe, rvec, tvec, first.intrinsics)
    seen = warped.gray > 0  # the warp's border is black

    def ncc(a: np.ndarray, b: np.ndarray) -> float:
        a, b = a[seen].astype(float) - a[seen].mean(), b[seen].astype(float) - b[seen].mean()
        return float(a @ b / np.sqrt((a @ a) * (b @ b)))

    frame = second.color[:, :, 0]
    assert seen.mean() > 0.5
    assert ncc(warped.gray, frame) > 0.9 > ncc(keyframe.gray, frame)  # it looks like the frame; unwarped it does not
    projected, _ = cv2.projectPoints(keyframe.points_3d, rvec, tvec, first.intrinsics.matrix, None)
    assert np.abs(warped.points_2d - projected.reshape(-1, 2)).max() < 1.0  # the corners where the motion puts them
