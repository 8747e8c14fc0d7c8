"""Issue 15 #8 (config): every out-of-range value is a ConfigError at load time naming its key path;
duplicate keys and pathological YAML are refused with a clear message instead of a traceback."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gprbot.config import load_config, parse_config
from gprbot.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("yaml_text", "path"),
    [
        ("gpr: {samples: 0}", "gpr.samples"),
        ("motion: {jog_deadman_timeout_s: .inf}", "motion.jog_deadman_timeout_s"),
        ("motion: {jog_max_speed_m_s: .nan}", "motion.jog_max_speed_m_s"),
        ("shell: {max_clients: 0}", "shell.max_clients"),
        ("shell: {rate_per_s: 0}", "shell.rate_per_s"),
        ("shell: {port: 70000}", "shell.port"),
        ("shell: {auth_timeout_s: -1}", "shell.auth_timeout_s"),
        ("survey: {lines: 0}", "survey.lines"),
        ("survey: {speed_m_s: -0.1}", "survey.speed_m_s"),
        ("survey: {start_xy_m: [0.0, .inf]}", "survey.start_xy_m[1]"),
        ("gpr: {eps_r: 0.5}", "gpr.eps_r"),
        ("gpr: {pre_trigger_ns: 20.0}", "gpr.pre_trigger_ns"),
        ("gpr_device: {stacks: 3}", "gpr_device.stacks"),
        ("motors: {wheel_map: [[128, 1], [128, 3], [129, 1]]}", "motors.wheel_map[1]"),
        ("motors: {command_timeout_s: 0}", "motors.command_timeout_s"),
        ("interpretation: {aperture_deg: 90}", "interpretation.aperture_deg"),
        ("reconstruction: {sparse_points: 0}", "reconstruction.sparse_points"),
        ("realsense: {reconnect_backoff_s: [8.0, 0.5]}", "realsense.reconnect_backoff_s"),
        ("runs_dir: ''", "runs_dir"),
    ],
)
def test_an_out_of_range_value_names_its_key_path(yaml_text: str, path: str) -> None:
    with pytest.raises(ConfigError, match="^" + re.escape(f"robot.yaml: {path}: ")):
        parse_config(yaml_text, "robot.yaml")


def test_a_key_given_twice_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"line 3: key 'samples' appears twice"):
        parse_config("gpr:\n  samples: 512\n  samples: 0\n", "robot.yaml")


def test_deep_nesting_is_a_config_error_not_a_recursion_error() -> None:
    with pytest.raises(ConfigError, match="nested more than"):
        parse_config("gpr: " + "[" * 50_000 + "]" * 50_000)


def test_an_alias_flood_is_refused() -> None:
    text = "a: &a [1, 2]\n" + "".join(f"b{i}: [*a, *a]\n" for i in range(40))
    with pytest.raises(ConfigError, match="aliases"):
        parse_config(text)


@pytest.mark.parametrize("name", ["configs/sim.yaml", "configs/robot.yaml", "configs/sim_learned.yaml",
                                  "gprbot/configs/sim.yaml", "gprbot/configs/robot.yaml",
                                  "gprbot/configs/sim_learned.yaml"])
def test_the_shipped_configs_are_in_range(name: str) -> None:
    load_config(REPO / name)
