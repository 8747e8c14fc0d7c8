"""Fault injection on every device link during a survey: the daemon's wheels-stopped latency, pause,
reconnect, resume and run-log integrity for each fault (the same scenarios as
tests/test_device_faults_in_survey.py, all of them). Run: `python -m benchmarks.bench_device_faults`.
"""

from __future__ import annotations

import os
import sys

import pytest

from benchmarks.machine import machine_description


def main() -> int:
    """Run every fault scenario; pytest prints each latency line (-s)."""
    print(machine_description())
    os.environ["GPRBOT_FAULT_MATRIX"] = "all"
    return int(pytest.main(["-q", "-s", "-p", "no:cacheprovider", "tests/test_device_faults_in_survey.py"]))


if __name__ == "__main__":
    sys.exit(main())
