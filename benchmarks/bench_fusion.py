"""Cost of pose estimation on one core: filter steps and updates, and visual odometry per frame.

Prints medians (µs or ms) beside the sensors' real rates and the share of one core each would take:
IMU messages (gyro 400 Hz + accel 250 Hz) through PoseFuser.push, one covariance step of the filter
(every propagation_step_s), a wheel update (50 Hz), a VO update (per keyframe, ~2-5 Hz), VO per frame
(30 fps), and the simulator's rendering per frame for reference.
Run: `.venv/bin/python -m benchmarks.bench_fusion`.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: set before numpy loads its BLAS

import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.machine import machine_description as describe_machine  # noqa: E402
from gprbot.config import FusionConfig  # noqa: E402
from gprbot.fusion.ekf import ErrorStateEkf  # noqa: E402
from gprbot.fusion.fuser import PoseFuser  # noqa: E402
from gprbot.fusion.so3 import matrix_to_quat  # noqa: E402
from gprbot.fusion.vo import RgbdOdometry  # noqa: E402
from gprbot.messages import VoMeasurement  # noqa: E402
from gprbot.motion.kinematics import KiwiKinematics  # noqa: E402
from gprbot.sim.camera import FloorCamera  # noqa: E402
from gprbot.sim.encoders import simulate_encoders  # noqa: E402
from gprbot.sim.imu import simulate_imu  # noqa: E402
from gprbot.sim.motion_truth import jog_ground_truth  # noqa: E402


def machine_description() -> str:
    """The machine, with the OpenCV version."""
    return describe_machine(f"OpenCV {cv2.__version__} (1 thread)")



def median_us(step: Callable[[], object], repeats: int) -> float:
    """Median wall time of one call, in microseconds (after a warm-up call)."""
    step()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter_ns()
        step()
        samples.append(time.perf_counter_ns() - start)
    return statistics.median(samples) / 1e3


def ready_filter() -> ErrorStateEkf:
    """A filter initialised at rest, with a VO clone, as it runs mid-survey."""
    ekf = ErrorStateEkf(FusionConfig(), KiwiKinematics(0.05, 0.15))
    ekf.initialize(0.0, np.array([0.0, 0.0, 9.80665]), np.zeros(3), np.zeros(3), 0.0)
    ekf.v = np.array([0.1, 0.0, 0.0])
    ekf.clone()
    return ekf


def main() -> None:
    """Measure and print."""
    cv2.setNumThreads(1)
    print(machine_description())
    truth = jog_ground_truth(30.0, seed=1)
    rows: list[tuple[str, float, float]] = []  # (what, cost µs, calls per second)

    messages = sorted(simulate_imu(truth).messages() + simulate_encoders(truth).messages(), key=lambda m: m.t)
    fuser = PoseFuser()
    start = time.perf_counter()
    for m in messages:
        fuser.push(m)
    per_message = (time.perf_counter() - start) / len(messages) * 1e6
    rows.append(("PoseFuser.push, IMU + wheel messages (mean)", per_message, 650.0 + 50.0))

    ekf = ready_filter()
    clock = [0.0]

    def propagate() -> None:
        clock[0] += 0.01
        ekf.propagate_to(clock[0])

    rows.append(("IMU propagate: one covariance step (every 10 ms)", median_us(propagate, 2000), 100.0))
    wheels = KiwiKinematics(0.05, 0.15).wheel_speeds([0.1, 0.0, 0.0])
    rows.append(("wheel update (3 rim speeds + 2 pseudo)", median_us(lambda: ekf.update_wheels(wheels), 2000), 50.0))
    vo = VoMeasurement(0.5, ekf.clone_t, "ok", matrix_to_quat(np.eye(3)), np.array([0.0, 0.0, 0.0]),
                       np.eye(6) * 1e-8, 100, False)
    rows.append(("VO update (relative pose, 6)", median_us(lambda: ekf.update_vo(vo), 2000), 5.0))
    rows.append(("VO re-clone (new keyframe)", median_us(ekf.clone, 2000), 5.0))

    camera = FloorCamera(seed=1)
    frames = list(camera.frames(truth, 2.0, 12.0))
    rows.append(("sim: render one RGB-D frame 424x240 (reference)",
                 median_us(lambda: camera.render_truth(5.0, truth), 100), 30.0))
    odometry = RgbdOdometry(camera.model.mount)
    costs = []
    for frame in frames:
        begin = time.perf_counter_ns()
        odometry.process(frame)
        costs.append((time.perf_counter_ns() - begin) / 1e3)
    rows.append(("VO per frame, 424x240 (median)", statistics.median(costs), 30.0))
    rows.append(("VO per frame, 424x240 (95th percentile)", float(np.percentile(costs, 95)), 30.0))

    print(f"{'what':<52} {'cost':>10} {'rate':>8} {'share of 1 core':>16}")
    for what, cost_us, rate in rows:
        cost = f"{cost_us:.1f} µs" if cost_us < 1000 else f"{cost_us / 1000:.2f} ms"
        print(f"{what:<52} {cost:>10} {rate:>6.0f}/s {100 * cost_us * rate / 1e6:>15.2f}%")


if __name__ == "__main__":
    main()
