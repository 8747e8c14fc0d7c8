"""Issue 15 #9: the unit's stop timeout covers the daemon's own shutdown budget, resources are capped,
the IP firewall admits loopback plus the config's networks only, and log lines carry journald priorities."""

from __future__ import annotations

import dataclasses
import ipaddress
import logging
from pathlib import Path

import pytest

from gprbot.config import load_config
from gprbot.daemon import JournalFormatter, configure_logging
from gprbot.errors import GprbotError
from gprbot.shutdown_budget import SHUTDOWN_BUDGET_S
from gprbot.systemd_unit import allowed_networks, main, network_dropin
from tests.test_systemd_files import UNIT, parse_unit

REPO = Path(__file__).resolve().parents[1]


def test_stop_timeout_exceeds_the_daemons_shutdown_budget() -> None:
    service = parse_unit(UNIT.read_text())["Service"]
    assert float(service["TimeoutStopSec"][0]) >= SHUTDOWN_BUDGET_S + 5.0  # 5 s for Python's own exit


def test_memory_and_tasks_are_capped() -> None:
    service = parse_unit(UNIT.read_text())["Service"]
    assert service["MemoryMax"] and service["MemoryHigh"] and int(service["TasksMax"][0]) <= 512
    assert service["SyslogLevelPrefix"] == ["yes"]


def test_the_unit_allows_loopback_only_and_the_dropin_adds_the_configs_networks() -> None:
    service = parse_unit(UNIT.read_text())["Service"]
    assert service["IPAddressDeny"] == ["any"] and service["IPAddressAllow"] == ["localhost"]
    cfg = load_config(REPO / "gprbot/configs/robot.yaml")
    cfg = dataclasses.replace(cfg, shell=dataclasses.replace(cfg.shell, allow_from=("192.168.10.7/24",)))
    assert allowed_networks(cfg) == ["localhost", "192.168.20.221/32", "192.168.10.0/24"]
    dropin = parse_unit(network_dropin(cfg))
    for entry in dropin["Service"]["IPAddressAllow"][0].split()[1:]:
        ipaddress.ip_network(entry)
    assert "10.0.0.0/8" not in network_dropin(cfg)


def test_a_nic_given_by_name_cannot_make_a_firewall_rule() -> None:
    cfg = load_config(REPO / "gprbot/configs/robot.yaml")
    cfg = dataclasses.replace(cfg, gpr_device=dataclasses.replace(cfg.gpr_device, host="nic.local"))
    with pytest.raises(GprbotError, match="not an IP address"):
        allowed_networks(cfg)


def test_the_dropin_command_prints_the_file(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--config", str(REPO / "gprbot/configs/robot.yaml")]) == 0
    assert "IPAddressAllow=localhost 192.168.20.221/32" in capsys.readouterr().out


def test_log_lines_under_systemd_carry_priorities() -> None:
    formatter = JournalFormatter("%(levelname)s %(name)s: %(message)s")
    for level, prefix in [(logging.CRITICAL, "<2>"), (logging.ERROR, "<3>"), (logging.WARNING, "<4>"),
                          (logging.INFO, "<6>"), (logging.DEBUG, "<7>")]:
        record = logging.LogRecord("gprbot.x", level, __file__, 1, "line one\nline two", None, None)
        text = formatter.format(record)
        assert text.startswith(prefix) and "\n" not in text


def test_configure_logging_uses_priorities_only_under_the_journal(monkeypatch: pytest.MonkeyPatch) -> None:
    root = logging.getLogger()
    saved = root.handlers[:]
    try:
        for env, journal in (({"JOURNAL_STREAM": "8:1234"}, True), ({}, False)):
            root.handlers = []
            configure_logging(env)
            assert isinstance(root.handlers[0].formatter, JournalFormatter) is journal
    finally:
        root.handlers = saved
