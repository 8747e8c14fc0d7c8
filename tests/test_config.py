"""Config loading: defaults, unknown keys and wrong types named by their key path."""

from __future__ import annotations

import pytest

from gprbot.config import Config, load_config, parse_config
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
