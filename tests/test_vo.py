"""RGB-D visual odometry on rendered floor frames: known motions, loss of tracking, keyframe chaining."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gprbot.fusion.so3 import exp_so3, log_so3, quat_to_matrix
from gprbot.fusion.vo import RgbdOdometry
from gprbot.fusion.vo_geometry import VoConfig, detect_keyframe, estimate_motion
from gprbot.geometry import CameraMount, d435i_intrinsics
from gprbot.messages import decode, encode
from gprbot.sim.camera import FloorCamera
from gprbot.sim.floor_texture import FloorSpec
from gprbot.sim.motion_truth import straight_ground_truth

SMALL_FLOOR = FloorSpec(size_px=(1024, 1024), smooth_patches_m=())
START = np.array([0.1, 0.2, 0.0])


@pytest.fixture(scope="module")
def camera() -> FloorCamera:
    return FloorCamera(SMALL_FLOOR, seed=1)


@pytest.mark.parametrize(
    ("shift_m", "yaw_deg"), [((0.02, 0.01, 0.0), 0.0), ((0.0, -0.03, 0.0), 0.0), ((0.015, 0.0, 0.0), 1.5)]
)
def test_vo_recovers_a_known_motion_between_two_frames(camera: FloorCamera, shift_m: tuple[float, ...],
                                                       yaw_deg: float) -> None:
    turn = exp_so3(np.array([0.0, 0.0, math.radians(yaw_deg)]))
    first = camera.render(0.0, np.eye(3), START)
    second = camera.render(0.1, turn, START + np.asarray(shift_m))
    vo = RgbdOdometry(camera.model.mount)
    assert [m.status for m in vo.process(first)] == ["keyframe"]
    assert vo.process(second) == []  # tracked, keyframe kept: nothing to report yet
    assert vo.last_estimate is not None
    R, t, covariance = vo.base_motion(vo.last_estimate)
    assert np.linalg.norm(t - np.asarray(shift_m)) < 0.001  # the brief: within ~1 mm
    assert math.degrees(np.linalg.norm(log_so3(turn.T @ R))) < 0.05
    assert np.all(np.sqrt(np.diag(covariance)[:3]) < 0.001)  # and VO knows it is that good


def test_camera_frame_motion_matches_the_mount_geometry(camera: FloorCamera) -> None:
    """The raw PnP result, before the base_link conversion: a base move of dx seen by the tilted camera."""
    config = VoConfig()
    first = camera.render(0.0, np.eye(3), START)
    second = camera.render(0.1, np.eye(3), START + np.array([0.01, 0.0, 0.0]))
    keyframe = detect_keyframe(0.0, first.color[:, :, 0], first.depth_m, first.intrinsics, config)
    assert keyframe is not None
    estimate = estimate_motion(keyframe, 0.1, second.color[:, :, 0], second.intrinsics, config)
    assert not isinstance(estimate, str)
    # Points stay, the camera moves +1 cm along base x: in camera coordinates points move by −R_cbᵀ·dx.
    expected = -CameraMount().rotation().T @ np.array([0.01, 0.0, 0.0])
    assert estimate.tvec == pytest.approx(expected, abs=0.001)


def test_vo_reports_loss_on_a_textureless_frame(camera: FloorCamera) -> None:
    plain = FloorCamera(FloorSpec(size_px=(256, 256), plain=True), seed=2)
    blank = plain.render(0.1, np.eye(3), START)
    assert detect_keyframe(0.1, blank.color[:, :, 0], blank.depth_m, blank.intrinsics, VoConfig()) is None
    vo = RgbdOdometry()
    vo.process(camera.render(0.0, np.eye(3), START))
    lost = vo.process(blank)
    assert [m.status for m in lost] == ["lost"]
    assert "texture" in lost[0].reason
    assert vo.process(plain.render(0.2, np.eye(3), START)) == []  # stays lost quietly, no garbage
    assert [m.status for m in vo.process(camera.render(0.3, np.eye(3), START))] == ["keyframe"]


def test_vo_keyframe_chain_follows_a_straight_drive(camera: FloorCamera) -> None:
    truth = straight_ground_truth(3.5, (0.1, 0.0), rest_s=0.5, seed=3)
    vo = RgbdOdometry(camera.model.mount)
    measurements = [m for frame in camera.frames(truth) for m in vo.process(frame)]
    assert measurements[0].status == "keyframe"
    steps = [m for m in measurements if m.status == "ok"]
    assert len(steps) >= 4 and all(m.new_keyframe for m in steps)
    assert all(later.t_ref == earlier.t for earlier, later in itertools.pairwise(steps))
    R, p = np.eye(3), np.zeros(3)
    for m in steps:
        p, R = p + R @ m.translation, R @ quat_to_matrix(m.rotation)
    times = np.array([measurements[0].t, steps[-1].t])
    true_R, true_p = truth.rotation(times), truth.position(times)
    true_step = true_R[0].T @ (true_p[1] - true_p[0])
    assert np.linalg.norm(true_step) > 0.2
    assert np.linalg.norm(p - true_step) < 0.002


def test_d435i_intrinsics_scale_from_the_native_sensor() -> None:
    k = d435i_intrinsics(640, 480)
    assert k.fx == pytest.approx(1380.0 * 480 / 1080)
    assert (k.cx, k.cy) == (319.5, 239.5)
    assert 2 * math.degrees(math.atan(212 / d435i_intrinsics(424, 240).fx)) == pytest.approx(69.4, abs=0.5)


def test_vo_messages_survive_the_run_log_codec(camera: FloorCamera) -> None:
    frame = camera.render(1.5, np.eye(3), START)
    assert np.array_equal(decode(encode(frame)).depth_m, frame.depth_m)
    vo = RgbdOdometry()
    vo.process(frame)
    (measurement,) = vo.process(camera.render(1.6, np.eye(3), START + np.array([0.06, 0.0, 0.0])))  # retires
    back = decode(encode(measurement))
    assert back.status == "ok" and back.new_keyframe is True and (back.t_ref, back.t) == (1.5, 1.6)
    assert np.array_equal(back.covariance, measurement.covariance)
