"""Progress bars (tqdm) for jobs longer than a few seconds; silent under --quiet and when stderr is not a TTY.

Bars go to stderr so that stdout stays the command's result (tables, --json). A daemon, a pipe, CI or a
log file never gets carriage-return noise: the bar is disabled unless stderr is a terminal.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator, Sized
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")
_quiet = False
tqdm.monitor_interval = 0  # no monitor thread: a bar here is updated by its job, and the daemon needs no extra thread


def set_quiet(quiet: bool) -> None:
    """Silence every bar of this process (`gprbot --quiet`)."""
    global _quiet
    _quiet = quiet


def enabled() -> bool:
    """Whether bars are shown: not --quiet, and stderr is a terminal."""
    return not _quiet and sys.stderr.isatty()


def bar(total: int | None, desc: str, unit: str = "step") -> tqdm[None]:
    """A bar to update by hand (e.g. one step per survey line); a no-op object when disabled."""
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=not enabled(), dynamic_ncols=True,
                leave=False)


def track(items: Iterable[T], desc: str, total: int | None = None, unit: str = "it") -> Iterator[T]:
    """Iterate with a bar (total from len() when it has one)."""
    if total is None and isinstance(items, Sized):
        total = len(items)
    yield from tqdm(items, total=total, desc=desc, unit=unit, file=sys.stderr, disable=not enabled(),
                    dynamic_ncols=True, leave=False)
