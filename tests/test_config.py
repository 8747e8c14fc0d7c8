"""Config loading: defaults, unknown keys and wrong types named by their key path."""

from __future__ import annotations

from pathlib import Path

import pytest

from gprbot.config import Config, load_config, model_path, parse_config
from gprbot.errors import ConfigError


def test_embedded_default_loads_and_matches_dataclass_defaults() -> None:
    cfg = load_config()
    assert isinstance(cfg, Config)
    assert cfg.survey.lines == 10
    assert cfg.gpr.eps_r is None
    assert cfg.motors.wheel_map == ((128, 1), (128, 2), (129, 1))


def test_unknown_key_names_its_path() -> None:
    with pytest.raises(ConfigError, match=r"survey\.spacing: unknown key"):
        parse_config("survey:\n  spacing: 0.1\n")


def test_wrong_type_names_path_and_expectation() -> None:
    with pytest.raises(ConfigError, match=r"gpr\.samples: expected an integer"):
        parse_config("gpr:\n  samples: many\n")
    with pytest.raises(ConfigError, match=r"mount\.antenna_lever_arm_m: expected a list of 3"):
        parse_config("mount:\n  antenna_lever_arm_m: [1, 2]\n")
    with pytest.raises(ConfigError, match=r"interpretation\.method: expected one of"):
        parse_config("interpretation:\n  method: magic\n")


def test_optional_and_nested_tuples() -> None:
    cfg = parse_config("gpr:\n  eps_r: 6\nmotors:\n  wheel_map: [[130, 1], [130, 2], [131, 1]]\n")
    assert cfg.gpr.eps_r == 6.0
    assert cfg.motors.wheel_map[2] == (131, 1)


def test_config_is_frozen() -> None:
    cfg = load_config()
    with pytest.raises(AttributeError):
        cfg.survey.lines = 3  # type: ignore[misc]


def test_bad_yaml_and_missing_file() -> None:
    with pytest.raises(ConfigError, match="not valid YAML"):
        parse_config("gpr: [unclosed\n")
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config("/nonexistent/gprbot.yaml")


def test_robot_config_loads_and_points_at_real_devices() -> None:
    from pathlib import Path

    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "robot.yaml")
    assert cfg.motors.port.startswith("/dev/serial/")
    assert cfg.gpr_device.host != "sim" and cfg.realsense.source == "device"
    # The acquisition grid the NIC accepts must match the processing's time axis.
    assert cfg.gpr.samples == cfg.gpr_device.points_per_trace
    assert cfg.gpr.time_window_ns == pytest.approx(cfg.gpr.samples * cfg.gpr_device.time_sampling_interval_ps / 1000)
    assert cfg.survey.trace_rate_hz == pytest.approx(1 / cfg.gpr_device.trigger_period_s)


def test_relative_model_paths_are_read_from_the_checkout_not_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # systemd starts the daemon in / ; a shell may be anywhere
    cfg = load_config()
    assert model_path(cfg.reconstruction.gprnet_model).is_file()
    assert model_path(cfg.interpretation.migrationnet_model).is_file()
    assert model_path("/opt/x.onnx") == Path("/opt/x.onnx")


def test_models_are_found_in_an_installed_wheel_or_models_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import gprbot.config as config_module
    from gprbot.errors import ModelError

    site = tmp_path / "site-packages"  # a wheel install: no checkout models/ beside the package
    packaged = site / "gprbot" / "models"
    packaged.mkdir(parents=True)
    (packaged / "gprnet.onnx").write_bytes(b"onnx")
    monkeypatch.setattr(config_module, "CHECKOUT_ROOT", site)
    monkeypatch.setattr(config_module, "PACKAGED_MODELS", packaged)
    assert model_path("models/gprnet.onnx") == packaged / "gprnet.onnx"  # before: site-packages/models/...
    with pytest.raises(ModelError, match="models_dir"):
        model_path("models/migrationnet.onnx")
    mine = tmp_path / "my-models"
    mine.mkdir()
    (mine / "migrationnet.onnx").write_bytes(b"onnx")
    assert model_path("models/migrationnet.onnx", str(mine)) == mine / "migrationnet.onnx"
    with pytest.raises(ModelError, match=f"not in models_dir {mine}"):
        model_path("models/gprnet.onnx", str(mine))


def test_builtin_configs_load_by_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # an installed gprbot: no configs/ directory in sight
    assert load_config("sim_learned").interpretation.method == "migrationnet"
    with pytest.raises(ConfigError, match="built-in configs: robot, sim, sim_learned"):
        load_config("no_such_config")


def test_the_nic_sampling_is_derived_from_gpr_and_checked_against_it() -> None:
    cfg = parse_config("gpr: {samples: 256, time_window_ns: 25.6}\n")
    assert cfg.gpr_device.points_per_trace == 256 and cfg.gpr_device.time_sampling_interval_ps == 100.0
    with pytest.raises(ConfigError, match=r"gpr_device\.points_per_trace: must equal gpr\.samples \(256\)"):
        parse_config("gpr: {samples: 256}\ngpr_device: {points_per_trace: 512}\n")
    with pytest.raises(ConfigError, match=r"gpr_device\.time_sampling_interval_ps: 50 ps × 512 is 25\.6 ns"):
        parse_config("gpr_device: {time_sampling_interval_ps: 50}\n")


def test_the_once_dead_device_keys_reach_the_drivers() -> None:
    from gprbot.drivers.gpr.driver import GprDriver
    from gprbot.drivers.realsense.driver import RealsenseDriver

    cfg = parse_config("realsense: {stall_timeout_s: 7.5, reconnect_backoff_s: [0.25, 4.0], "
                       "clock_jump_threshold_s: 0.3}\ngpr_device: {stall_timeout_s: 2.5}\n")
    camera = RealsenseDriver(cfg.realsense)
    assert (camera.stall_timeout_s, camera.backoff_initial_s, camera.backoff_max_s, camera.jump_threshold_s) == (
        7.5, 0.25, 4.0, 0.3)
    assert GprDriver(cfg.gpr_device)._stall_timeout_s == 2.5
    assert GprDriver(load_config().gpr_device)._stall_timeout_s == 1.0  # unset: 50 trigger periods, at least 1 s


def test_one_place_for_the_shell_port_and_the_control_period() -> None:
    from gprbot.config import CONTROL_PERIOD_S, DEFAULT_SHELL_PORT
    from gprbot.drivers.motors import safety
    from gprbot.robot import runtime
    from gprbot.shell import client

    assert load_config().shell.port == DEFAULT_SHELL_PORT == client.DEFAULT_PORT
    assert safety.CONTROL_PERIOD_S is runtime.CONTROL_PERIOD_S is CONTROL_PERIOD_S
