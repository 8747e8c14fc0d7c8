"""Async helpers for the tests."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import TypeVar

T = TypeVar("T")


async def within(awaitable: Awaitable[T], timeout_s: float | None) -> T:
    """Await `awaitable` under asyncio.timeout (not wait_for: on 3.11 that can swallow a cancel)."""
    async with asyncio.timeout(timeout_s):
        return await awaitable
