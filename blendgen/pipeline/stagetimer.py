"""CPU and wall seconds per named stage, summed over a run (for ``dockbench bench suite``).

CPU is :func:`time.process_time`: every thread of this process (Cycles' render threads
included), so on a shared machine it is the work done, while wall also counts waiting.

Inside a stage, :func:`term` splits it into named terms (``compose.water``,
``compose.sensor``, ...): each term's seconds exclude the terms nested in it, so the
terms of a stage never add up to more than the stage (the rest is ``<stage>.other``
in the bench's tables). Outside a timed stage (the closed loop, tests) :func:`term`
measures nothing.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

_ACTIVE: list = []  # [(timer, stage)] of the stages open in this process, innermost last
_TERMS: list[list[float]] = []  # [cpu, wall] already taken by nested terms, per open term


class StageTimer:
    """``with timer("render"): ...`` adds the block's CPU and wall seconds to stage ``render``."""

    def __init__(self):
        self.cpu_s: dict[str, float] = {}
        self.wall_s: dict[str, float] = {}

    def add(self, stage: str, cpu_s: float, wall_s: float) -> None:
        self.cpu_s[stage] = self.cpu_s.get(stage, 0.0) + cpu_s
        self.wall_s[stage] = self.wall_s.get(stage, 0.0) + wall_s

    @contextmanager
    def __call__(self, stage: str):
        c0, w0 = time.process_time(), time.perf_counter()
        _ACTIVE.append((self, stage))
        try:
            yield
        finally:
            _ACTIVE.pop()
            self.add(stage, time.process_time() - c0, time.perf_counter() - w0)

    def totals(self) -> dict[str, float]:
        """``{"cpu_<stage>_s": s, "wall_<stage>_s": s}`` for every stage (and term) timed."""
        out = {f"cpu_{k}_s": v for k, v in self.cpu_s.items()}
        out.update({f"wall_{k}_s": v for k, v in self.wall_s.items()})
        return out


@contextmanager
def term(name: str):
    """Time the block as term ``<stage>.<name>`` of the innermost open stage (its seconds
    minus those of terms nested in it); no-op when no stage is open."""
    if not _ACTIVE:
        yield
        return
    timer, stage = _ACTIVE[-1]
    c0, w0 = time.process_time(), time.perf_counter()
    _TERMS.append([0.0, 0.0])
    try:
        yield
    finally:
        inner_cpu, inner_wall = _TERMS.pop()
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        timer.add(f"{stage}.{name}", cpu - inner_cpu, wall - inner_wall)
        if _TERMS:  # the enclosing term does not count this one again
            _TERMS[-1][0] += cpu
            _TERMS[-1][1] += wall
