"""The swarm page's runner: steps on the wall clock, pushes each step to the open pages, at most display_hz."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

pytest.importorskip("nicegui")
from sims.console.app import SwarmRunner  # noqa: E402


class _Op:
    """A swarm whose step only counts (the runner needs ``config.dt``, ``k`` and ``tick``)."""

    def __init__(self, dt: float):
        self.config = SimpleNamespace(dt=dt)
        self.k = 0

    def tick(self) -> None:
        self.k += 1


def _watch(runner: SwarmRunner, seconds: float, subscribe: bool = True) -> list[int]:
    drawn: list[int] = []

    async def main() -> None:
        if subscribe:
            runner.subscribe(lambda: drawn.append(runner.op.k))
        task = asyncio.ensure_future(runner.run())
        await asyncio.sleep(seconds)
        task.cancel()
        await asyncio.sleep(0.2)  # a push deferred to the end of its display period

    asyncio.run(main())
    return drawn


def test_every_step_is_pushed_once_in_order_when_the_display_rate_is_higher():
    """Steps slower than display_hz: each step reaches the page once, none skipped, none twice."""
    runner = SwarmRunner(_Op(dt=0.02), display_hz=200.0)
    drawn = _watch(runner, 0.5)
    assert len(drawn) >= 5
    assert drawn == list(range(1, runner.op.k + 1))


def test_pushes_are_capped_at_the_display_rate_and_the_newest_step_is_shown():
    """Steps four times faster than display_hz: about display_hz pushes a second, the last one the newest step."""
    runner = SwarmRunner(_Op(dt=0.005), display_hz=20.0)
    drawn = _watch(runner, 0.6)
    assert runner.op.k > 2 * len(drawn)
    assert len(drawn) <= 20 * 0.6 + 2
    assert drawn == sorted(set(drawn)) and drawn[-1] == runner.op.k


def test_nothing_steps_while_no_page_is_open_or_the_swarm_is_paused():
    """The swarm stands still with no page open, and while paused."""
    runner = SwarmRunner(_Op(dt=0.01))
    _watch(runner, 0.2, subscribe=False)
    assert runner.op.k == 0
    runner.running = False
    assert _watch(runner, 0.2) == [] and runner.op.k == 0


def test_runner_refuses_a_rate_that_is_not_positive():
    """A display rate or speed of zero is refused when the runner is made, not when it first steps."""
    with pytest.raises(ValueError):
        SwarmRunner(_Op(dt=0.1), display_hz=0.0)
    with pytest.raises(ValueError):
        SwarmRunner(_Op(dt=0.1), rate=-1.0)
