"""Polling for a condition, for tests and tools (``from waiting import wait_for`` in tests;
``from tests.waiting import wait_for`` elsewhere in the checkout).

A test never sleeps to wait: it waits for the condition it needs, within a time budget scaled by
``timeout_scale()`` (tests/conftest.py, TANKVIZ_TEST_TIMEOUT_SCALE), e.g.
``assert wait_for(lambda: live.pipeline.frames >= sent, 10 * timeout_scale())``. A condition that
holds ends the wait at once; the budget is only what a slow machine may take at most."""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Awaitable, Callable


def timeout_scale() -> float:
    """TANKVIZ_TEST_TIMEOUT_SCALE (default 1): a factor on the tests' time budgets, for a slow or
    loaded machine. The budgets are what a wait for a condition may take at most; a condition
    that holds ends its wait at once."""
    raw = os.environ.get("TANKVIZ_TEST_TIMEOUT_SCALE", "").strip() or "1"
    try:
        scale = float(raw)
    except ValueError:
        scale = 0.0
    if not scale > 0:
        raise ValueError(f"TANKVIZ_TEST_TIMEOUT_SCALE={raw!r}: expected a number > 0")
    return scale


def wait_for(condition: Callable[[], bool], timeout: float = 5.0, step: float = 0.01) -> bool:
    """Poll ``condition`` until true or ``timeout`` (for tools and tests)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step)
    return condition()


async def wait_for_async(condition: Callable[[], Awaitable[bool]], timeout: float = 5.0,
                         step: float = 0.0) -> bool:
    """:func:`wait_for` in a coroutine: awaits ``condition`` until true or ``timeout`` (it may
    itself wait for something, e.g. a message: then ``step`` may be 0)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if await condition():
            return True
        await asyncio.sleep(step)
    return await condition()
