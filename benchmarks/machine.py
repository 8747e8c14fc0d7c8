"""The machine a benchmark ran on, printed beside its figures so they can be read and compared."""

from __future__ import annotations

import os
import platform

import numpy as np


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux), else the architecture."""
    try:
        with open("/proc/cpuinfo") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_description(extra: str = "") -> str:
    """Platform, CPU, usable cores, load and library versions (plus `extra`, e.g. a library's version)."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    text = (
        f"{platform.platform()} | {cpu_model()}, {os.cpu_count()} logical CPUs ({usable} usable), load {load:.1f} | "
        f"Python {platform.python_version()}, numpy {np.__version__}"
    )
    return f"{text}, {extra}" if extra else text
