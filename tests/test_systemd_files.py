"""The systemd unit, sysusers and udev files: required settings present, syntax valid, systemd agrees."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

SYSTEMD = Path(__file__).resolve().parents[1] / "systemd"
UNIT = SYSTEMD / "gprbot.service"
RULES = SYSTEMD / "99-gprbot.rules"
SYSUSERS = SYSTEMD / "gprbot.sysusers"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """Sections → key → every value given (unit files repeat keys such as DeviceAllow=)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        header = re.fullmatch(r"\[(\w+)\]", line)
        if header:
            current = sections.setdefault(header.group(1), {})
            continue
        key, sep, value = line.partition("=")
        assert sep and current is not None and re.fullmatch(r"[A-Z][A-Za-z]+", key), f"line {number}: {raw!r}"
        current.setdefault(key, []).append(value)
    return sections


@pytest.fixture(scope="module")
def unit() -> dict[str, dict[str, list[str]]]:
    return parse_unit(UNIT.read_text())


def test_unit_is_a_notify_service_with_watchdog_and_restart(unit: dict[str, dict[str, list[str]]]) -> None:
    service = unit["Service"]
    expected = {
        "Type": "notify", "NotifyAccess": "main", "WatchdogSec": "10", "Restart": "on-failure",
        "User": "gprbot", "StateDirectory": "gprbot",
        "ExecStart": "/opt/gprbot/.venv/bin/gprbot run --config /etc/gprbot/robot.yaml",
    }
    for key, value in expected.items():
        assert service[key] == [value], key
    assert 0 < float(service["RestartSec"][0]) < 10
    assert set(service["SupplementaryGroups"][0].split()) == {"dialout", "video", "plugdev"}
    assert unit["Install"]["WantedBy"] == ["multi-user.target"]


def test_unit_hardening(unit: dict[str, dict[str, list[str]]]) -> None:
    service = unit["Service"]
    for key, value in {
        "ProtectSystem": "strict", "ProtectHome": "yes", "PrivateTmp": "yes", "NoNewPrivileges": "yes",
        "DevicePolicy": "closed", "CapabilityBoundingSet": "", "RestrictNamespaces": "yes",
    }.items():
        assert service[key] == [value], key
    allowed = {entry.split()[0] for entry in service["DeviceAllow"]}
    assert allowed == {"char-usb_device", "char-ttyUSB", "char-ttyACM", "char-video4linux", "char-hidraw"}
    assert set(service["RestrictAddressFamilies"][0].split()) == {"AF_UNIX", "AF_INET", "AF_INET6", "AF_NETLINK"}
    assert service["SystemCallFilter"][0] == "@system-service"
    assert "ReadWritePaths" not in service  # the state directory is the only writable place


def test_sysusers_creates_the_user_in_the_units_groups(unit: dict[str, dict[str, list[str]]]) -> None:
    entries = [line.split() for line in SYSUSERS.read_text().splitlines() if line and not line.startswith("#")]
    assert entries[0][:2] == ["u", "gprbot"]
    assert {e[2] for e in entries if e[:2] == ["m", "gprbot"]} == set(unit["Service"]["SupplementaryGroups"][0].split())


_RULE_ITEM = re.compile(r'\s*([A-Z_]+)(\{[^}]+\})?\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*')
_MATCH_KEYS = {"ACTION", "SUBSYSTEM", "SUBSYSTEMS", "KERNEL", "DRIVER", "ATTR", "ATTRS", "ENV"}
_ASSIGN_KEYS = {"MODE", "GROUP", "SYMLINK", "ENV", "ATTR"}


def parse_rules(text: str) -> list[list[tuple[str, str, str, str]]]:
    """Each rule as (key, {attr}, operator, value) items; asserts every item is well-formed."""
    rules = []
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        items = []
        for part in line.split('",'):
            part = part if part.endswith('"') else part + '"'
            item = _RULE_ITEM.fullmatch(part)
            assert item, f"line {number}: cannot parse {part!r}"
            key, attr, op, value = item.group(1), item.group(2) or "", item.group(3), item.group(4)
            if op in ("==", "!="):
                assert key in _MATCH_KEYS, f"line {number}: {key} is not a match key"
            else:
                assert key in _ASSIGN_KEYS, f"line {number}: {key} cannot be assigned"
            items.append((key, attr, op, value))
        assert any(op in ("==", "!=") for _, _, op, _ in items), f"line {number}: rule matches everything"
        rules.append(items)
    return rules


def test_udev_rules_parse_and_cover_the_devices() -> None:
    rules = parse_rules(RULES.read_text())

    def rules_with(*pairs: tuple[str, str]) -> list[list[tuple[str, str, str, str]]]:
        def has(rule: list[tuple[str, str, str, str]], key: str, value: str) -> bool:
            return any(f"{k}{a}" == key and v == value for k, a, _, v in rule)

        return [rule for rule in rules if all(has(rule, key, value) for key, value in pairs)]

    realsense = rules_with(("ATTRS{idVendor}", "8086"), ("ATTRS{idProduct}", "0b3a"))
    assert realsense and ("GROUP", "", "=", "plugdev") in realsense[0]
    roboclaw = rules_with(("ATTRS{idVendor}", "03eb"), ("ATTRS{idProduct}", "2404"))
    assert roboclaw and any(k == "SYMLINK" and v.startswith("gprbot/") for k, _, _, v in roboclaw[0])
    ftdi = rules_with(("ATTRS{idVendor}", "0403"))
    assert ftdi and ("GROUP", "", "=", "dialout") in ftdi[0]
    latency = rules_with(("DRIVER", "ftdi_sio"))
    assert latency and ("ATTR", "{latency_timer}", "=", "1") in latency[0]


def test_rule_parser_rejects_typos() -> None:
    with pytest.raises(AssertionError):
        parse_rules('SUBSYSTEM=="tty", GROUP=="dialout" MODE="0660"')
    with pytest.raises(AssertionError):
        parse_rules('SUBSYSTEM="tty", GROUP="dialout"')


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_analyze_verifies_the_unit_and_rates_it_ok(tmp_path: Path) -> None:
    # verify insists that ExecStart exists; the venv is not installed here, so point it at /bin/true
    copy = tmp_path / "gprbot.service"
    copy.write_text(re.sub(r"(?m)^ExecStart=.*$", "ExecStart=/bin/true", UNIT.read_text()))
    verify = subprocess.run(["systemd-analyze", "verify", str(copy)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0 and "gprbot.service" not in verify.stderr, verify.stderr
    security = subprocess.run(
        ["systemd-analyze", "security", "--offline=yes", str(copy)], capture_output=True, text=True, timeout=60
    )
    score = re.search(r"Overall exposure level for gprbot\.service: ([\d.]+)", security.stdout)
    assert score, security.stdout[-500:] + security.stderr
    assert float(score.group(1)) <= 2.0  # "OK"; 1.5 when written
