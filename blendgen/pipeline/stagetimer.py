"""CPU and wall seconds per named stage, summed over a run (for ``dockbench bench suite``).

CPU is :func:`time.process_time`: every thread of this process (Cycles' render threads
included), so on a shared machine it is the work done, while wall also counts waiting.
"""

from __future__ import annotations

import time
from contextlib import contextmanager


class StageTimer:
    """``with timer("render"): ...`` adds the block's CPU and wall seconds to stage ``render``."""

    def __init__(self):
        self.cpu_s: dict[str, float] = {}
        self.wall_s: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        c0, w0 = time.process_time(), time.perf_counter()
        try:
            yield
        finally:
            self.cpu_s[stage] = self.cpu_s.get(stage, 0.0) + time.process_time() - c0
            self.wall_s[stage] = self.wall_s.get(stage, 0.0) + time.perf_counter() - w0

    def totals(self) -> dict[str, float]:
        """``{"cpu_<stage>_s": s, "wall_<stage>_s": s}`` for every stage timed."""
        out = {f"cpu_{k}_s": v for k, v in self.cpu_s.items()}
        out.update({f"wall_{k}_s": v for k, v in self.wall_s.items()})
        return out
