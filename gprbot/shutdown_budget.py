"""The daemon's shutdown budget: how long each step after SIGTERM may take (systemd's TimeoutStopSec exceeds it)."""

from __future__ import annotations

SHUTDOWN_STEPS_S = {"stop the wheels and end the run": 10.0, "cancel the tasks": 5.0,
                    "close the devices and the worker": 10.0}
SHUTDOWN_BUDGET_S = sum(SHUTDOWN_STEPS_S.values())
