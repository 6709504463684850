"""Run render jobs in worker processes, with progress on stderr.

Each job is a fresh ``python -m blendgen.blender.worker`` process: Blender is
imported once per camera path and its memory is returned to the system when the
job ends (Blender leaks across many renders). ``workers`` processes run at once;
each gets ``threads`` Cycles threads so the cores are not oversubscribed.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable


class RenderError(RuntimeError):
    """A worker process failed; the message carries the tail of its log."""


def default_workers(n_jobs: int) -> int:
    """Processes to run at once: one per core pair, at most one per job."""
    return max(1, min(n_jobs, (os.cpu_count() or 1) // 2))


def threads_per_worker(workers: int) -> int:
    return max(1, (os.cpu_count() or 1) // workers)


def run_worker(job_file: Path, log_file: Path) -> None:
    """Run one render job to completion; raise RenderError with the log tail on failure."""
    cmd = [sys.executable, "-m", "blendgen.blender.worker", str(job_file)]
    with open(log_file, "ab") as log:
        rc = subprocess.run(cmd, stdout=log, stderr=log, stdin=subprocess.DEVNULL).returncode
    if rc != 0:
        tail = log_file.read_text(errors="replace").splitlines()[-25:]
        raise RenderError(f"render worker failed (exit {rc}) for {job_file.name}:\n" + "\n".join(tail))


class Progress:
    """Polls frames.jsonl line counts and prints one refreshed line to stderr."""

    def __init__(self, total: int, count: Callable[[], int], label: str = "rendering"):
        self.total, self.count, self.label = total, count, label
        self._stop = threading.Event()
        self._t0 = time.perf_counter()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._print(final=True)

    def _loop(self):
        tty = sys.stderr.isatty()
        while not self._stop.wait(1.0 if tty else 15.0):
            self._print()

    def _print(self, final: bool = False):
        done = min(self.count(), self.total)
        dt = time.perf_counter() - self._t0
        rate = done / dt if dt > 0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else float("nan")
        end = "\n" if final or not sys.stderr.isatty() else "\r"
        sys.stderr.write(f"{self.label}: {done}/{self.total} frames ({100 * done / max(self.total, 1):.0f}%)"
                         f" {rate:.1f} frames/s, eta {eta:.0f} s   {end}")
        sys.stderr.flush()


def run_local(job_files: list[Path], log_dir: Path, workers: int,
              on_done: Callable[[Path], None]) -> None:
    """Run job files on a local process pool; ``on_done(job_file)`` after each success."""
    def one(jf: Path):
        run_worker(jf, log_dir / f"{jf.stem}.log")
        on_done(jf)

    with ThreadPoolExecutor(max_workers=workers) as pool:
        for fut in [pool.submit(one, jf) for jf in job_files]:
            fut.result()


def write_job(job: dict, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(job))
    return path
