"""The one message registry: every message type is in it, its rates resolve, and nothing registers on import."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np

from gprbot import messages
from gprbot.config import CONTROL_PERIOD_S, Config, RealsenseConfig
from gprbot.drivers.health import DriverHealth
from gprbot.messages import REGISTRY, WheelEncoders, encode, expected_rates

REPO = Path(__file__).resolve().parents[1]


def test_every_message_dataclass_of_the_module_is_registered() -> None:
    defined = {name for name, obj in vars(messages).items()
               if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == messages.__name__
               and "t" in {f.name for f in dataclasses.fields(obj)}}
    assert defined == set(REGISTRY)


def test_expected_rates_follow_the_config() -> None:
    cfg = Config()
    rates = expected_rates(cfg)
    assert rates["gpr"] == cfg.survey.trace_rate_hz and rates["motors"] == 1.0 / CONTROL_PERIOD_S
    assert rates["realsense.gyro"] == cfg.realsense.gyro_hz and rates["realsense.color"] == cfg.realsense.fps
    fast = dataclasses.replace(cfg, realsense=RealsenseConfig(gyro_hz=200, accel_hz=63))
    assert REGISTRY["ImuSample"].expected_hz(fast) == 263.0
    assert REGISTRY["SurveyEvent"].expected_hz(cfg) is None


def test_frames_are_logged_only_when_the_config_says() -> None:
    cfg = Config()
    assert not REGISTRY["RawRgbdFrame"].is_logged(cfg) and REGISTRY["Trace"].is_logged(cfg)
    recording = dataclasses.replace(cfg, realsense=RealsenseConfig(record_frames=True))
    assert REGISTRY["RawRgbdFrame"].is_logged(recording)


def test_a_stream_under_half_its_rate_is_slow() -> None:
    h = DriverHealth("gpr", connected=True, rate_hz=9.0, drops=0, errors=0, last_error=None, last_message_t=1.0)
    assert h.slow_against(20.0) and not h.slow_against(15.0) and not h.slow_against(None)
    assert not dataclasses.replace(h, connected=False).slow_against(20.0)


def test_the_run_log_reader_decodes_driver_messages_without_importing_drivers(tmp_path: Path) -> None:
    path = tmp_path / "encoders.bin"
    path.write_bytes(encode(WheelEncoders(1.0, np.array([1, 2, 3], dtype=np.int64), np.zeros(3))))
    code = (f"import sys, gprbot.runlog_reader, gprbot.messages as m; "
            f"msg = m.decode(open({str(path)!r}, 'rb').read()); "
            f"bad = [k for k in sys.modules if k.startswith('gprbot.drivers')]; "
            f"sys.exit(0 if type(msg).__name__ == 'WheelEncoders' and not bad else 1)")
    assert subprocess.run([sys.executable, "-c", code], cwd=REPO, timeout=60).returncode == 0
