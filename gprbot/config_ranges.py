"""Value ranges of the configuration, checked at load time: every error names its key path.

Types are `config.py`'s business; this table says what values make sense for a robot (a sample count
of 0 divides by zero in a task, an infinite deadman timeout never stops a jog, `max_clients: 0` locks
every operator out). Every float must be finite unless the table says otherwise.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import math
from dataclasses import dataclass
from typing import Any

from gprbot.errors import ConfigError


@dataclass(frozen=True)
class Range:
    """low..high; `low_open`/`high_open` exclude the bound itself."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False

    def check(self, value: float) -> bool:
        """Whether value lies in the range."""
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def text(self) -> str:
        """The range as an interval, e.g. (0, 10]."""
        return f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"


def positive(high: float = math.inf) -> Range:
    """(0, high]."""
    return Range(0.0, high, low_open=True)


def at_least(low: float, high: float = math.inf) -> Range:
    """[low, high]."""
    return Range(low, high)


PORT = Range(1, 65535)
PORT_OR_EPHEMERAL = Range(0, 65535)  # 0: any free port (tests, the demo)
BAUD = positive(1e7)

RANGES: dict[str, Range] = {
    "gpr.centre_frequency_mhz": positive(10_000),
    "gpr.samples": at_least(16, 65_536),
    "gpr.time_window_ns": positive(10_000),
    "gpr.pre_trigger_ns": at_least(0, 10_000),
    "gpr.antenna_height_m": at_least(0, 1),
    "gpr.tx_rx_offset_m": at_least(0, 2),
    "gpr.noise_mv": at_least(0, 1e5),
    "gpr.eps_r": at_least(1, 81),
    "mount.antenna_lever_arm_m": Range(-5, 5),
    "mount.camera_position_m": Range(-5, 5),
    "mount.camera_pitch_down_deg": at_least(0, 90),
    "survey.lines": at_least(1, 10_000),
    "survey.spacing_m": positive(100),
    "survey.length_m": positive(10_000),
    "survey.speed_m_s": positive(5),
    "survey.settle_s": at_least(0, 600),
    "survey.start_xy_m": Range(-1e5, 1e5),
    "survey.trace_rate_hz": positive(10_000),
    "pose_noise.position_std_m": at_least(0, 10),
    "pose_noise.yaw_std_deg": at_least(0, 180),
    "pose_noise.drift_m_per_m": at_least(0, 1),
    "interpretation.aperture_deg": Range(0, 90, low_open=True, high_open=True),
    "interpretation.mask_threshold": at_least(0, 1),
    "interpretation.min_score": at_least(0, 1),
    "interpretation.depth_max_m": positive(100),
    "reconstruction.sparse_points": at_least(1, 1_000_000),
    "reconstruction.dense_points": at_least(1, 1_000_000),
    "reconstruction.cluster_distance_m": positive(100),
    "reconstruction.min_slices_per_pipe": at_least(1, 10_000),
    "reconstruction.model_threads": at_least(1, 256),
    "motors.baudrate": BAUD,
    "motors.encoder_counts_per_rev": at_least(1, 1e9),
    "motors.wheel_radius_m": positive(2),
    "motors.base_radius_m": positive(10),
    "motors.max_wheel_speed_rad_s": positive(10_000),
    "motors.max_wheel_accel_rad_s2": positive(1e6),
    "motors.command_timeout_s": positive(10),
    "motors.retries": at_least(0, 100),
    "motors.failsafe_timeout_s": positive(60),
    "gpr_device.http_port": PORT_OR_EPHEMERAL,
    "gpr_device.data_port": PORT_OR_EPHEMERAL,
    "gpr_device.points_per_trace": at_least(1, 65_536),
    "gpr_device.time_sampling_interval_ps": positive(1e6),
    "gpr_device.stacks": at_least(1, 32_768),
    "gpr_device.window_shift_ns": Range(-1e4, 1e4),
    "gpr_device.trigger_period_s": positive(60),
    "gpr_device.connect_timeout_s": positive(600),
    "gpr_device.stall_timeout_s": positive(600),
    "realsense.gyro_hz": positive(10_000),
    "realsense.accel_hz": positive(10_000),
    "realsense.width": at_least(1, 10_000),
    "realsense.height": at_least(1, 10_000),
    "realsense.fps": at_least(1, 1000),
    "realsense.stall_timeout_s": positive(600),
    "realsense.reconnect_backoff_s": positive(3600),
    "realsense.clock_jump_threshold_s": positive(3600),
    "motion.heading_kp_per_s": at_least(0, 1000),
    "motion.heading_ki_per_s2": at_least(0, 1000),
    "motion.heading_kd_gyro": at_least(0, 1000),
    "motion.max_heading_omega_rad_s": positive(100),
    "motion.jog_max_speed_m_s": positive(5),
    "motion.jog_deadman_timeout_s": positive(10),
    "motion.jog_max_duration_s": positive(86_400),
    "shell.port": PORT_OR_EPHEMERAL,
    "shell.max_clients": at_least(1, 1024),
    "shell.rate_per_s": positive(1e6),
    "shell.max_unauthenticated": at_least(1, 1024),
    "shell.auth_timeout_s": positive(3600),
    "shell.idle_timeout_s": positive(1e7),
    "shell.serial_baudrate": BAUD,
}


KNOWN_TOP_MAX_DEPTH_M = 5.0  # a known cover deeper than this is no slab's (gpr.known_tops, replay --known-top)


def check_ranges(config: Any) -> None:
    """Raise ConfigError (naming the key path) for the first value outside its range or not finite."""
    _walk(config, "")
    _check_relations(config)


def _walk(node: Any, path: str) -> None:
    if dataclasses.is_dataclass(node) and not isinstance(node, type):
        for f in dataclasses.fields(node):
            _walk(getattr(node, f.name), f"{path}.{f.name}" if path else f.name)
        return
    if isinstance(node, tuple):
        for i, item in enumerate(node):
            _walk_value(item, f"{path}[{i}]", path)
        return
    _walk_value(node, path, path)


def _walk_value(value: Any, path: str, key: str) -> None:
    if isinstance(value, tuple):
        for i, item in enumerate(value):
            _walk_value(item, f"{path}[{i}]", key)
        return
    if isinstance(value, bool) or not isinstance(value, int | float):
        return
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{path}: expected a finite number, got {value!r}")
    bounds = RANGES.get(key)
    if bounds is not None and not bounds.check(value):
        raise ConfigError(f"{path}: expected a value in {bounds.text()}, got {value!r}")


def _check_relations(config: Any) -> None:
    gpr, device, motors, realsense = config.gpr, config.gpr_device, config.motors, config.realsense
    if gpr.pre_trigger_ns >= gpr.time_window_ns:
        raise ConfigError(f"gpr.pre_trigger_ns: must be less than gpr.time_window_ns ({gpr.time_window_ns:g}), "
                          f"got {gpr.pre_trigger_ns:g}")
    if gpr.known_tops and gpr.eps_r is not None:
        raise ConfigError("gpr.known_tops: the velocity is fixed by gpr.eps_r already; set one of the two "
                          "(eps_r: null to calibrate on the known tops)")
    for i, (_, _, depth) in enumerate(gpr.known_tops):
        if not 0.0 < depth <= KNOWN_TOP_MAX_DEPTH_M:
            raise ConfigError(f"gpr.known_tops[{i}]: the third number is the depth of the target's top below the "
                              f"surface, in (0, {KNOWN_TOP_MAX_DEPTH_M:g}] m; got {depth:g}")
    if device.points_per_trace != gpr.samples:
        raise ConfigError(f"gpr_device.points_per_trace: must equal gpr.samples ({gpr.samples}), got "
                          f"{device.points_per_trace}; leave it out to derive it from gpr")
    device_window_ns = device.points_per_trace * device.time_sampling_interval_ps / 1000.0
    if not math.isclose(device_window_ns, gpr.time_window_ns, rel_tol=1e-9):
        raise ConfigError(f"gpr_device.time_sampling_interval_ps: {device.time_sampling_interval_ps:g} ps × "
                          f"{device.points_per_trace} is {device_window_ns:g} ns, but gpr.time_window_ns is "
                          f"{gpr.time_window_ns:g}; leave it out to derive it from gpr")
    if device.stacks & (device.stacks - 1):
        raise ConfigError(f"gpr_device.stacks: expected a power of 2 (1, 2, 4, ... 32768), got {device.stacks}")
    if len(motors.wheel_map) != 3:
        raise ConfigError(f"motors.wheel_map: expected 3 wheels (address, channel), got {len(motors.wheel_map)}")
    for i, (address, channel) in enumerate(motors.wheel_map):
        if not 128 <= address <= 135 or channel not in (1, 2):
            raise ConfigError(f"motors.wheel_map[{i}]: expected [address 128..135, channel 1 or 2], "
                              f"got [{address}, {channel}]")
    if len(set(motors.wheel_map)) != 3:
        raise ConfigError(f"motors.wheel_map: two wheels on the same controller channel: {motors.wheel_map}")
    for i, (address, _) in enumerate(motors.controller_ports):
        if not 128 <= address <= 135:
            raise ConfigError(f"motors.controller_ports[{i}]: expected an address 128..135, got {address}")
    for i, net in enumerate(config.shell.allow_from):
        try:
            ipaddress.ip_network(net, strict=False)
        except ValueError:
            raise ConfigError(f"shell.allow_from[{i}]: expected a subnet like 192.168.10.0/24, got {net!r}") from None
    low, high = realsense.reconnect_backoff_s
    if low > high:
        raise ConfigError(f"realsense.reconnect_backoff_s: the first wait ({low:g}) exceeds the longest ({high:g})")
    if not config.runs_dir:
        raise ConfigError("runs_dir: expected a directory, got an empty string")
