"""The simulated robot: the real drivers against its emulators, its true motion and its sensors."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import math

import numpy as np

from gprbot.config import load_config
from gprbot.drivers.gpr.driver import GprDriver
from gprbot.drivers.motors import protocol as rc
from gprbot.drivers.motors.driver import MotorDriver
from gprbot.messages import ImuSample, WheelSpeeds
from gprbot.motion.kinematics import KiwiKinematics, planar_pose_message
from gprbot.motion.planner import Segment
from gprbot.robot.tracking import tracking_velocity
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.imu import ImuModel
from gprbot.simulated.robot import GRAVITY_M_S2, SimRobot
from gprbot.survey import start_pose


def test_the_default_config_is_the_simulated_robot_starting_with_the_antenna_on_the_start_point() -> None:
    cfg = load_config()
    assert cfg.simulated
    x, y, yaw = start_pose(cfg)
    lever = cfg.mount.antenna_lever_arm_m
    assert (x + lever[0], y + lever[1], yaw) == (*cfg.survey.start_xy_m, 0.0)


async def test_true_pose_follows_the_emulated_wheels_through_the_real_motor_driver() -> None:
    cfg = load_config()
    robot = SimRobot(cfg)
    driven = await robot.start()
    motors = MotorDriver(driven.motors)
    await motors.start()
    try:
        wheel_map = cfg.motors.wheel_map
        angle0 = np.array([robot.motors.encoder_position(a, c) for a, c in wheel_map])
        pose0 = robot.pose.copy()
        command = KiwiKinematics.from_config(cfg.motors).wheel_speeds((0.2, 0.0, 0.0))
        loop = asyncio.get_running_loop()
        end = loop.time() + 0.6
        while loop.time() < end:
            await motors.set_wheel_speeds(WheelSpeeds(loop.time(), command))
            robot.advance()
            await asyncio.sleep(0.01)
        await motors.stop()
        await asyncio.sleep(0.3)  # the motors' lag: let them come to rest
        robot.advance()
        counts = np.array([robot.motors.encoder_position(a, c) for a, c in wheel_map]) - angle0
    finally:
        await motors.close()
        await robot.close()
    # Independent truth: the emulator's closed-form encoder positions over the wheels' true radii.
    turned_rad = counts * 2 * math.pi / cfg.motors.encoder_counts_per_rev
    expected = robot.kinematics.body_twist(turned_rad * robot.radius_scale)
    moved = robot.pose - pose0
    assert 0.1 < moved[0] < 0.13  # ~0.2 m/s for 0.6 s, less the motors' ramps
    np.testing.assert_allclose(moved[:2], expected[:2], atol=2e-3)
    assert abs(moved[2] - expected[2]) < 2e-3
    assert abs(moved[2]) > 1e-3  # unequal wheel radii turn the robot: heading hold has work to do


async def test_gpr_traces_are_the_forward_model_at_the_true_antenna_position() -> None:
    cfg = load_config()
    robot = SimRobot(cfg)
    lever = cfg.mount.antenna_lever_arm_m[0]
    robot.pose = np.array([0.35 - lever, 0.5, 0.0])  # antenna straight above the steel pipe (x = 0.35 m)
    driven = await robot.start()
    driver = GprDriver(driven.gpr_device)
    await driver.start()
    traces = []
    try:
        async with asyncio.timeout(10):
            async for trace in driver.traces():
                traces.append(trace)
                if len(traces) == 10:
                    break
    finally:
        await driver.close()
        await robot.close()
    assert traces[0].dt_ns == cfg.gpr.dt_ns and traces[0].t0_ns == cfg.gpr.pre_trigger_ns
    assert traces[0].samples.size == cfg.gpr.samples
    assert robot.traces_served >= 10
    quiet = dataclasses.replace(cfg.gpr, noise_mv=0.0)
    rng = np.random.default_rng(1)
    above = simulate_bscan(robot.scene, np.array([[0.35, 0.5]]), quiet, rng)[0]
    beside = simulate_bscan(robot.scene, np.array([[0.55, 0.5]]), quiet, rng)[0]
    mean = np.mean([t.samples for t in traces], axis=0)
    late = slice(int(3.0 / cfg.gpr.dt_ns), None)  # past the direct and ground waves, where the pipe echoes

    def corr(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.corrcoef(a[late], b[late])[0, 1])

    assert corr(mean, above) > 0.9
    assert corr(mean, above) > corr(mean, beside) + 0.2


async def test_imu_streams_at_rest_have_their_rates_and_gravity() -> None:
    cfg = load_config()
    robot = SimRobot(cfg)
    samples: list[ImuSample] = []
    batches = robot.imu_batches(period_s=0.01)
    async with asyncio.timeout(5):
        while not samples or samples[-1].t - samples[0].t < 1.0:
            samples.extend(await anext(batches))
    await batches.aclose()
    gyro = [s for s in samples if s.gyro is not None]
    accel = [s for s in samples if s.accel is not None]
    span = samples[-1].t - samples[0].t
    assert abs(len(gyro) / span - 400) < 10 and abs(len(accel) / span - 250) < 10
    assert all(b.t >= a.t for a, b in itertools.pairwise(samples))
    mean_accel = np.mean([s.accel for s in accel], axis=0)
    assert abs(mean_accel[2] - GRAVITY_M_S2) < 0.25 and np.all(np.abs(mean_accel[:2]) < 0.25)
    mean_gyro = np.mean([s.gyro for s in gyro], axis=0)
    assert np.all(np.abs(mean_gyro) < math.radians(1.0))  # at rest: only the turn-on bias


def test_plan_tracking_pulls_the_antenna_back_onto_the_plan() -> None:
    lever = (0.25, 0.0, 0.0)
    segment = Segment("line", 0.0, 2.0, np.array([0.0, 0.0]), np.array([0.4, 0.0]), 0)
    on_plan = planar_pose_message(10.0, (0.2 - 0.25, 0.0, 0.0))  # 1 s into the line: antenna at x = 0.2
    np.testing.assert_allclose(tracking_velocity(segment, 1.0, 10.0, on_plan, lever), [0.2, 0.0], atol=1e-12)
    # The pose is 0.1 s old: the plan was 0.02 m behind then, so a pose there is on the plan too.
    trailing = planar_pose_message(9.9, (0.18 - 0.25, 0.0, 0.0))
    np.testing.assert_allclose(tracking_velocity(segment, 1.0, 10.0, trailing, lever), [0.2, 0.0], atol=1e-12)
    right_of_plan = planar_pose_message(10.0, (0.2 - 0.25, -0.02, 0.0))
    np.testing.assert_allclose(tracking_velocity(segment, 1.0, 10.0, right_of_plan, lever), [0.2, 0.02], atol=1e-12)
    far = planar_pose_message(10.0, (0.2 - 0.25, -0.5, 0.0))
    np.testing.assert_allclose(tracking_velocity(segment, 1.0, 10.0, far, lever, max_correction_m_s=0.05),
                               [0.2, 0.05], atol=1e-12)
    turned = planar_pose_message(10.0, (0.2 - 0.25 * math.cos(0.1), -0.25 * math.sin(0.1), 0.1))
    np.testing.assert_allclose(tracking_velocity(segment, 1.0, 10.0, turned, lever), [0.2, 0.0], atol=1e-12)
    stale = planar_pose_message(9.0, (0.0, -0.5, 0.0))
    np.testing.assert_allclose(tracking_velocity(segment, 1.0, 10.0, stale, lever), [0.2, 0.0])


async def test_the_simulated_imu_is_the_same_however_late_the_loop_gets_round_to_it() -> None:
    """A stalled loop makes the simulator catch up later, not differently: the IMU samples of a stop
    inside a 0.4 s stall match those made in 10 ms steps (before, the whole stall got one mean
    acceleration and the last turn rate, so the filter integrated a motion that never happened)."""
    cfg = load_config()
    quiet = ImuModel(gyro_noise_density=0.0, accel_noise_density=0.0, gyro_turn_on_bias_std=0.0,
                     accel_turn_on_bias_std=0.0, gyro_lsb=1e-9, accel_lsb=1e-9)

    async def record(steps: list[float]) -> tuple[list[ImuSample], np.ndarray]:
        now = [100.0]
        robot = SimRobot(cfg, clock=lambda: now[0], imu_model=quiet)
        emu = robot.motors
        emu.receive(rc.set_serial_timeout(128, 0.1).encode() + rc.set_serial_timeout(129, 0.1).encode())
        emu.receive(rc.drive_speeds(128, 800, -400).encode() + rc.drive_speeds(129, -400, 0).encode())
        batches = robot.imu_batches(period_s=0.0)
        samples = list(await anext(batches))
        for dt in steps:  # no byte after the commands: each controller's failsafe stops it 0.1 s later
            now[0] += dt
            samples.extend(await anext(batches))
        await batches.aclose()
        return samples, robot.pose.copy()

    regular, pose_regular = await record([0.01] * 50)
    stalled, pose_stalled = await record([0.05, 0.4, 0.05])
    np.testing.assert_allclose(pose_stalled, pose_regular, atol=2e-4)
    accel = {round(s.t, 6): s.accel for s in regular if s.accel is not None}
    pairs = [(accel[round(s.t, 6)], s.accel) for s in stalled if s.accel is not None and round(s.t, 6) in accel]
    assert len(pairs) > 100
    peak = max(abs(float(a[0])) for a, _ in pairs)
    assert peak > 0.5  # the stop is in there: the wheels decelerate (failsafe, then the motors' lag)
    worst = max(float(np.max(np.abs(a - b))) for a, b in pairs)
    assert worst < 0.05 * peak, f"stalled IMU differs by {worst:.3f} m/s² (peak {peak:.3f})"
