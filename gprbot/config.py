"""Typed, frozen configuration loaded from YAML.

Every section is a frozen dataclass; `load_config` checks every key and type and raises ConfigError
naming the key path (e.g. `survey.spacing_m`) and what was expected. The simulated robot's config
(`gprbot/configs/sim.yaml`) is the embedded default.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml

from gprbot.config_ranges import check_ranges
from gprbot.errors import ConfigError, ModelError

Vec3 = tuple[float, float, float]


DEFAULT_SHELL_PORT = 7878  # the operator's shell (shell.port; `gprbot shell HOST` without a port)
CONTROL_PERIOD_S = 0.02  # the motion loop's period (50 Hz); the motors' fault bound and the encoder poll follow


@dataclass(frozen=True)
class GprConfig:
    """The GPR antenna and its acquisition settings."""

    centre_frequency_mhz: float = 900.0
    samples: int = 512
    time_window_ns: float = 12.0
    pre_trigger_ns: float = 1.0  # where time zero (the transmit instant) sits in each trace
    antenna_height_m: float = 0.02
    tx_rx_offset_m: float = 0.05
    noise_mv: float = 0.5
    eps_r: float | None = None  # known slab permittivity; None: estimate velocity from hyperbolas
    # Targets whose cover is known (a cover meter reading, a core): (x, y, depth of the target's top), site frame,
    # m. The survey's velocity is calibrated on them (gprbot/infer/known_tops.py) instead of estimated.
    known_tops: tuple[Vec3, ...] = ()

    @property
    def dt_ns(self) -> float:
        """Sample interval: sample k lies at k * dt_ns - pre_trigger_ns after the transmit instant."""
        return self.time_window_ns / self.samples


@dataclass(frozen=True)
class MountConfig:
    """Where the antenna sits on the robot: the midpoint of Tx and Rx in the base frame (m)."""

    antenna_lever_arm_m: Vec3 = (0.25, 0.0, 0.0)
    camera_position_m: Vec3 = (0.20, 0.0, 0.30)  # D435i optical centre in the base frame: measure on the robot
    camera_pitch_down_deg: float = 60.0


@dataclass(frozen=True)
class SurveyConfig:
    """A boustrophedon survey: parallel lines along x, stepping sideways in y, never rotating."""

    lines: int = 10
    spacing_m: float = 0.1
    length_m: float = 2.0
    speed_m_s: float = 0.1
    settle_s: float = 1.0
    start_xy_m: tuple[float, float] = (0.0, 0.0)
    trace_rate_hz: float = 20.0  # GPR traces per second (time-triggered; positions come from poses)


@dataclass(frozen=True)
class PoseNoiseConfig:
    """Noise added to the planned trajectory when no fusion runs (simulation only)."""

    position_std_m: float = 0.003
    yaw_std_deg: float = 0.2
    drift_m_per_m: float = 0.002
    seed: int = 1


@dataclass(frozen=True)
class InterpretationConfig:
    """How each B-scan becomes a cross-section and detections."""

    method: Literal["classical", "chain", "migrationnet"] = "classical"
    migrationnet_model: str = "models/migrationnet.onnx"  # used when method is migrationnet; see model_path()
    # The chain's pipes whose hyperbola does not measure the radius: the middle of what the curve allows ("fit"),
    # or MigrationNet's pipe mask at their top (the model above): better diameters, worse centres on the FDTD test
    # half (validation/README.md), so not the default
    radius_from: Literal["fit", "migrationnet"] = "fit"
    migration: Literal["kirchhoff", "stolt"] = "kirchhoff"
    aperture_deg: float = 35.0
    mask_threshold: float = 0.5
    min_score: float = 0.2
    depth_max_m: float = 0.6


@dataclass(frozen=True)
class ReconstructionConfig:
    """Registration of slices in 3D and completion into a dense cloud."""

    # geometric: the axis + radius fit; extended: the fit with every free pipe end pushed on to the survey's
    # edge; refined: the fit continued and corrected by the FitRefiner (models/fit_refiner.onnx; measured, it accepts
    # every continued point, so only its corrections differ);
    # gprnet: GPRNet's dense cloud on the fit's pipes. extended is the default: end to end it measures as well as
    # refined (models/eval_end_to_end.md) without a network
    completion: Literal["geometric", "extended", "refined", "gprnet"] = "extended"
    # The resampling/completion RNG's seed. None: sim.seed, which seeded it before this key existed, so
    # older configs and run logs reconstruct to the same bytes; set it on the robot, which has no sim.
    seed: int | None = None
    sparse_points: int = 1500
    dense_points: int = 8192
    cluster_distance_m: float = 0.08
    min_slices_per_pipe: int = 2
    gprnet_model: str = "models/gprnet.onnx"  # used when completion is gprnet; see model_path()
    refiner_model: str = "models/fit_refiner.onnx"  # used when completion is refined
    model_threads: int = 2


@dataclass(frozen=True)
class MotorsConfig:
    """RoboClaw packet-serial motor controllers driving the three omni wheels."""

    port: str = "sim"  # "sim": the RoboClaw emulator on a pty; else e.g. /dev/serial/by-id/usb-...
    baudrate: int = 115200  # TTL multi-unit line only (must match the controllers); USB ignores it
    # (controller address, channel 1|2) for wheels 0, 1, 2 — the order of the kinematics matrix rows
    wheel_map: tuple[tuple[int, int], ...] = ((128, 1), (128, 2), (129, 1))
    # (address, port) for controllers on their own USB port; addresses not listed use `port`
    controller_ports: tuple[tuple[int, str], ...] = ()
    encoder_counts_per_rev: int = 1024
    wheel_radius_m: float = 0.05
    base_radius_m: float = 0.15  # d: centre of the robot to each wheel
    max_wheel_speed_rad_s: float = 20.0
    max_wheel_accel_rad_s2: float = 40.0
    command_timeout_s: float = 0.02  # (1 + retries) × this + one 20 ms control period <= 0.1 s
    retries: int = 2
    failsafe_timeout_s: float = 0.1  # the controller's own serial timeout: it stops if we go quiet

    @property
    def poll_rate_hz(self) -> float:
        """How often the runtime reads the encoders: once per control period."""
        return 1.0 / CONTROL_PERIOD_S


@dataclass(frozen=True)
class GprDeviceConfig:
    """The GPR antenna's acquisition interface (Sensors & Software SDK mode)."""

    host: str = "sim"  # "sim": the SDK-mode emulator on loopback; else the NIC's address
    http_port: int = 8080
    data_port: int = 8081  # fallback only: the driver asks the NIC for its port (api/nic/gpr/data_socket)
    points_per_trace: int = 512
    time_sampling_interval_ps: float = 23.4375  # sim grid (12 ns / 512); a real NIC takes 50..6400 in steps of 50
    stacks: int = 4
    window_shift_ns: float = -1.0  # relative to the unit's calibrated reference: time zero lands 1 ns into the trace
    trigger_period_s: float = 0.01
    connect_timeout_s: float = 2.0
    stall_timeout_s: float | None = None  # no data this long: a stall, socket reopened (None: 50 periods, ≥ 1 s)


@dataclass(frozen=True)
class RealsenseConfig:
    """The Intel RealSense D435i: IMU and RGB-D streams."""

    source: str = "sim"  # "sim", "device" (first D435i found) or a serial number
    playback: str | None = None  # a recording (.db3; legacy .bag) played once, as fast as consumed, instead of a device
    gyro_hz: int = 400
    accel_hz: int = 250
    width: int = 424  # one mode for depth and colour; 424x240 keeps VO near 14 % of a core at 30 fps (640x480: 16 %)
    height: int = 240
    fps: int = 30
    stall_timeout_s: float = 3.0  # no frame for this long: the camera counts as lost and is reopened
    reconnect_backoff_s: tuple[float, float] = (0.5, 8.0)  # first and longest wait between reopen attempts
    clock_jump_threshold_s: float = 0.1  # device clock steps beyond this re-anchor the host-time conversion
    # Raw RGB-D frames into the run log (replay then re-runs VO on them). Off by default: uncompressed they
    # are ~300 kB per 424x240 pair, 9 MB/s at 30 fps; the VO measurements are always logged (~0.3 kB each).
    record_frames: bool = False


@dataclass(frozen=True)
class MotionConfig:
    """Heading hold and jog limits (the robot never rotates: ω comes only from heading hold)."""

    heading_kp_per_s: float = 3.0
    heading_ki_per_s2: float = 1.5
    heading_kd_gyro: float = 0.05
    max_heading_omega_rad_s: float = 0.2
    jog_max_speed_m_s: float = 0.3
    jog_deadman_timeout_s: float = 0.5
    jog_max_duration_s: float = 60.0


@dataclass(frozen=True)
class FusionConfig:
    """Noise model and bookkeeping of the pose filter (the `fusion:` config section; units in the names)."""

    gyro_noise_rad_s_sqrt_hz: float = 3.0e-4  # BMI055 2.44e-4 plus quantisation
    accel_noise_m_s2_sqrt_hz: float = 2.0e-3  # BMI055 1.47e-3 plus quantisation
    gyro_bias_walk_rad_s2_sqrt_hz: float = 2.0e-5
    accel_bias_walk_m_s3_sqrt_hz: float = 2.0e-4
    wheel_scale_walk_per_sqrt_s: float = 1.0e-4  # tyre wear, load shifts
    initial_position_std_m: float = 1.0e-4
    initial_velocity_std_m_s: float = 0.01
    initial_tilt_std_deg: float = 0.5
    initial_yaw_std_deg: float = 0.01  # the start heading defines odom
    initial_gyro_bias_std_rad_s: float = 2.0e-3  # after the at-rest mean
    initial_accel_bias_std_m_s2: float = 0.1
    initial_wheel_scale_std: float = 0.02
    wheel_rim_speed_std_m_s: float = 0.01  # encoder quantisation over a 20 ms poll, roller ripple
    wheel_slip_std: float = 0.02  # fraction of the rim speed
    wheel_speed_delay_s: float = 0.01  # a speed averaged over a 20 ms poll describes its middle
    vertical_speed_std_m_s: float = 0.005
    floor_height_std_m: float = 0.01  # a slab is level: odom z stays at its start value (0 turns this off)
    vo_covariance_scale: float = 1.0
    vo_translation_floor_m: float = 5.0e-5
    vo_rotation_floor_rad: float = 5.0e-5
    vo_map_slots: int = 20  # map keyframes the filter keeps a pose clone for (fusion.vo_map; 0: none)
    gate_probability: float = 0.999  # χ² gate on each update's normalised innovation
    max_consecutive_rejections: int = 25  # then accept anyway: a filter must not shut a sensor out for good
    init_duration_s: float = 0.5  # at rest: mean accel gives roll/pitch (and mean gyro the gyro bias)
    gyro_bias_from_rest: bool = True  # False: start from zero bias (when the start is not at rest)
    reorder_window_s: float = 0.1  # messages are processed this long after the newest one, in time order
    max_imu_wait_s: float = 2.0  # a lagging IMU holds the others back this long at most (then: a dead IMU)
    max_wheel_wait_s: float = 0.3  # lagging wheel readings hold the others back this long at most
    propagation_step_s: float = 0.01  # IMU samples are averaged over this before each covariance step
    output_rate_hz: float = 100.0
    history_s: float = 900.0  # output poses kept for pose_at

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool):
                continue
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"fusion.{f.name}: expected a finite number ≥ 0, got {value!r}")
        if not 0.5 < self.gate_probability < 1.0:
            raise ConfigError(
                f"fusion.gate_probability: expected a probability in (0.5, 1), got {self.gate_probability}"
            )
        if self.output_rate_hz <= 0.0:
            raise ConfigError(f"fusion.output_rate_hz: expected a positive rate, got {self.output_rate_hz}")
        if not (isinstance(self.vo_map_slots, int) and self.vo_map_slots <= 40):
            # each slot is six more filter states; 40 keeps a covariance step under ~0.1 ms
            raise ConfigError(f"fusion.vo_map_slots: expected a whole number 0-40, got {self.vo_map_slots!r}")


@dataclass(frozen=True)
class ShellConfig:
    """The operator's command shell: TCP (token required beyond loopback) and an optional serial console."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_SHELL_PORT
    token_file: str | None = None  # a 0600 file owned by the daemon's user; required when host is not loopback
    max_clients: int = 8  # authenticated sessions at once
    rate_per_s: float = 20.0
    max_unauthenticated: int = 2  # sessions still to authenticate; each gets auth_timeout_s (estop always works)
    auth_timeout_s: float = 10.0
    idle_timeout_s: float = 1800.0  # an authenticated session without input this long is closed
    # Operators' subnets (CIDR): the shell refuses other peers (loopback always allowed), and the
    # systemd drop-in (python -m gprbot.systemd_unit) opens the firewall to them. Empty: any peer.
    allow_from: tuple[str, ...] = ()
    serial_console: str | None = None  # e.g. /dev/serial/by-id/usb-FTDI_...; None: no serial shell
    serial_baudrate: int = 115200


@dataclass(frozen=True)
class WebConfig:
    """The operator's web console, served by the daemon; beyond loopback it takes the shell's token."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = 8780
    session_ttl_s: float = 43200.0  # a login lasts one working day
    status_hz: float = 4.0  # status and trace pushes to each browser
    max_traces_per_s: float = 25.0  # per browser; a faster GPR is stacked down to this


@dataclass(frozen=True)
class SimConfig:
    """The simulated world used when no hardware is attached."""

    scene: str = "paper_slab"
    seed: int = 0
    # Where the demo's pose estimate comes from: "fused" runs the real filter on simulated IMU, wheel
    # encoders and camera (VO); "noise" perturbs the true path by `pose_noise` (fast, for tests).
    poses: Literal["fused", "noise"] = "fused"


@dataclass(frozen=True)
class GeoreferenceConfig:
    """Where the site frame lies on the earth (for GeoJSON, and DXF/CSV in a projected CRS)."""

    heading_deg: float = 0.0  # azimuth of site +x, clockwise from (grid) north
    origin_lat_deg: float | None = None  # WGS84 latitude of the site origin
    origin_lon_deg: float | None = None
    origin_height_m: float = 0.0  # ellipsoidal height (WGS84) or the CRS's height of the origin
    crs: str | None = None  # a projected CRS for DXF/CSV, e.g. "EPSG:25832" (ETRS89 / UTM 32N)
    origin_easting_m: float | None = None
    origin_northing_m: float | None = None

    def __post_init__(self) -> None:
        if (self.origin_lat_deg is None) != (self.origin_lon_deg is None):
            raise ConfigError("georeference: give both origin_lat_deg and origin_lon_deg, or neither")
        if self.origin_lat_deg is not None and not -90.0 <= self.origin_lat_deg <= 90.0:
            raise ConfigError(f"georeference.origin_lat_deg: expected −90…90, got {self.origin_lat_deg}")
        if self.origin_lon_deg is not None and not -180.0 <= self.origin_lon_deg <= 180.0:
            raise ConfigError(f"georeference.origin_lon_deg: expected −180…180, got {self.origin_lon_deg}")
        if self.crs is not None and (self.origin_easting_m is None or self.origin_northing_m is None):
            raise ConfigError("georeference.crs: also give origin_easting_m and origin_northing_m of the site origin")
        if self.crs is None and self.origin_lat_deg is None:
            raise ConfigError("georeference: give origin_lat_deg/origin_lon_deg, or crs with origin_easting_m/"
                              "origin_northing_m (or leave the section out)")
        if not math.isfinite(self.heading_deg):
            raise ConfigError(f"georeference.heading_deg: expected a finite angle, got {self.heading_deg}")


@dataclass(frozen=True)
class RetentionConfig:
    """How many old runs the robot keeps in runs_dir; the oldest are deleted when a new run starts."""

    max_runs: int | None = None  # None: keep every run
    max_total_gb: float | None = None  # None: no size limit

    def __post_init__(self) -> None:
        if self.max_runs is not None and self.max_runs < 1:
            raise ConfigError(f"retention.max_runs: expected ≥ 1 (or null to keep all), got {self.max_runs}")
        if self.max_total_gb is not None and not self.max_total_gb > 0:
            raise ConfigError(f"retention.max_total_gb: expected > 0 (or null), got {self.max_total_gb}")


SIMULATED = "sim"  # the address (motors.port, gpr_device.host, realsense.source) of a device the simulator emulates


@dataclass(frozen=True)
class Config:
    """The whole gprbot configuration."""

    gpr: GprConfig = field(default_factory=GprConfig)
    mount: MountConfig = field(default_factory=MountConfig)
    survey: SurveyConfig = field(default_factory=SurveyConfig)
    pose_noise: PoseNoiseConfig = field(default_factory=PoseNoiseConfig)
    interpretation: InterpretationConfig = field(default_factory=InterpretationConfig)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    motors: MotorsConfig = field(default_factory=MotorsConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    shell: ShellConfig = field(default_factory=ShellConfig)
    web: WebConfig = field(default_factory=WebConfig)
    gpr_device: GprDeviceConfig = field(default_factory=GprDeviceConfig)
    realsense: RealsenseConfig = field(default_factory=RealsenseConfig)
    runs_dir: str = "runs"
    retention: RetentionConfig = field(default_factory=RetentionConfig)
    georeference: GeoreferenceConfig | None = None
    models_dir: str | None = None  # where model files are looked up by name (default: checkout or package)

    @property
    def reconstruction_seed(self) -> int:
        """The seed of the reconstruction's RNG (reconstruction.seed, else sim.seed as before that key)."""
        return self.sim.seed if self.reconstruction.seed is None else self.reconstruction.seed

    @property
    def simulated(self) -> bool:
        """Whether the config selects the simulated robot (any device addressed as SIMULATED)."""
        return SIMULATED in (self.motors.port, self.gpr_device.host, self.realsense.source)

    @property
    def all_simulated(self) -> bool:
        """Whether every device is the simulated robot's (mixing simulated and real ones is refused)."""
        return self.motors.port == self.gpr_device.host == self.realsense.source == SIMULATED


CHECKOUT_ROOT = Path(__file__).resolve().parents[1]


PACKAGED_MODELS = Path(__file__).resolve().parent / "models"  # where a wheel puts models/ (setup.py)


def model_path(configured: str, models_dir: str | None = None) -> Path:
    """A configured model file: absolute as given; else by name in models_dir when set; else in the checkout's
    models/ or, in an installed wheel, the packaged copy (gprbot/models). ModelError says where it looked."""
    path = Path(configured).expanduser()
    if path.is_absolute():
        return path
    if models_dir is not None:
        found = Path(models_dir).expanduser() / path.name
        if not found.is_file():
            raise ModelError(f"model {path.name} is not in models_dir {models_dir} (config key models_dir); "
                             "copy the .onnx file and its .json card there, or unset models_dir")
        return found
    candidates = [CHECKOUT_ROOT / path]
    if path.parts and path.parts[0] == "models":
        candidates.append(PACKAGED_MODELS.joinpath(*path.parts[1:]))
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise ModelError(f"model {configured} not found (looked in {', '.join(str(c) for c in candidates)}); "
                     "set models_dir in the config to the directory holding the .onnx files and their cards")


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _convert(value: Any, tp: Any, path: str) -> Any:
    """Check `value` against the annotation `tp` and convert it (lists → tuples, int → float)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: expected a mapping of {tp.__name__} keys, got {value!r}")
        return build_dataclass(tp, value, path)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, path)
            except ConfigError as exc:
                errors.append(str(exc))
        if len(errors) == 1:
            raise ConfigError(errors[0])
        raise ConfigError(f"{path}: expected {_type_name(tp)}, got {value!r}")
    if origin is Literal:
        if value not in args:
            choices = ", ".join(repr(a) for a in args)
            raise ConfigError(f"{path}: expected one of {choices}, got {value!r}")
        return value
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{path}: expected a list, got {value!r}")
        return tuple(_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value))
    if origin is tuple:
        if not isinstance(value, list | tuple) or len(value) != len(args):
            raise ConfigError(f"{path}: expected a list of {len(args)} numbers, got {value!r}")
        return tuple(_convert(v, a, f"{path}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{path}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {value!r}")
        return value
    raise ConfigError(f"{path}: unsupported config type {_type_name(tp)}")  # a bug in a dataclass


def build_dataclass(cls: type[Any], data: dict[str, Any], path: str = "") -> Any:
    """Build a frozen dataclass from a mapping, rejecting unknown keys and wrong types."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in data.items():
        key_path = f"{path}.{key}" if path else str(key)
        if key not in names:
            known = ", ".join(sorted(names))
            raise ConfigError(f"{key_path}: unknown key (known keys here: {known})")
        kwargs[key] = _convert(value, hints[key], key_path)
    return cls(**kwargs)


MAX_YAML_DEPTH = 16  # a config is a few levels deep; thousands of levels overflow the YAML composer's stack
MAX_YAML_ALIASES = 64  # anchors/aliases expand: a "billion laughs" file would take the memory


class _StrictLoader(yaml.SafeLoader):
    """safe_load that refuses a key given twice in one mapping (the second silently won)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, Any] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            if isinstance(key, typing.Hashable) and key in seen:
                line = key_node.start_mark.line + 1
                raise ConfigError(f"line {line}: key {key!r} appears twice in the same section; keep one")
            seen[key] = True
        return super().construct_mapping(node, deep=deep)


def _check_yaml_shape(text: str) -> None:
    """Refuse deep nesting and alias floods from the event stream (iterative, so it cannot overflow)."""
    depth = aliases = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.MappingStartEvent | yaml.SequenceStartEvent):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                line = event.start_mark.line + 1 if event.start_mark else "?"
                raise ConfigError(f"line {line}: nested more than {MAX_YAML_DEPTH} levels deep; a config is not")
        elif isinstance(event, yaml.MappingEndEvent | yaml.SequenceEndEvent):
            depth -= 1
        elif isinstance(event, yaml.AliasEvent):
            aliases += 1
            if aliases > MAX_YAML_ALIASES:
                raise ConfigError(f"more than {MAX_YAML_ALIASES} YAML aliases (*name); write the values out")


def _derive_sampling(data: dict[str, Any]) -> dict[str, Any]:
    """The sampling is defined once, by gpr.samples and gpr.time_window_ns: the NIC's points_per_trace and
    time_sampling_interval_ps follow from them unless written out (then check_ranges holds them to it)."""
    gpr, device = data.get("gpr"), data.get("gpr_device")
    if not isinstance(gpr, dict) or not isinstance(device, dict | None):
        return data  # no sampling given, or a shape build_dataclass reports
    samples, window = gpr.get("samples", GprConfig.samples), gpr.get("time_window_ns", GprConfig.time_window_ns)
    if not isinstance(samples, int) or isinstance(samples, bool) or not isinstance(window, int | float) or samples <= 0:
        return data
    derived = {"points_per_trace": samples, "time_sampling_interval_ps": 1000.0 * window / samples}
    return {**data, "gpr_device": {**derived, **(device or {})}}


def parse_config(text: str, source: str = "<string>") -> Config:
    """Parse YAML text into a Config (types checked, then value ranges)."""
    try:
        _check_yaml_shape(text)
        data = yaml.load(text, Loader=_StrictLoader)  # a SafeLoader subclass: no arbitrary objects
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML ({exc})") from exc
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the top level must be a mapping of sections")
    try:
        config: Config = build_dataclass(Config, _derive_sampling(data))
        check_ranges(config)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    return config


def load_config(path: str | Path | None = None) -> Config:
    """Load a config file, or a built-in one by name (sim, sim_learned, robot); with no path, configs/sim.yaml."""
    if path is None:
        text = resources.files("gprbot").joinpath("configs/sim.yaml").read_text()
        return parse_config(text, "configs/sim.yaml")
    p = Path(path)
    builtin = resources.files("gprbot").joinpath(f"configs/{p.name}.yaml")
    if not p.exists() and p.name == str(path) and builtin.is_file():  # a built-in name: works from a wheel too
        return parse_config(builtin.read_text(), f"configs/{p.name}.yaml")
    try:
        text = p.read_text()
    except OSError as exc:
        names = ", ".join(sorted(f.name.removesuffix(".yaml") for f in resources.files("gprbot").joinpath("configs")
                                 .iterdir() if f.name.endswith(".yaml")))
        raise ConfigError(f"cannot read config file {p}: {exc.strerror} (built-in configs: {names})") from exc
    return parse_config(text, str(p))


def to_dict(config: Any) -> Any:
    """The resolved config as plain data (for run headers and summaries)."""
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        return {f.name: to_dict(getattr(config, f.name)) for f in dataclasses.fields(config)}
    if isinstance(config, tuple):
        return [to_dict(v) for v in config]
    return config
