"""Run render jobs in worker processes, with progress on stderr.

One job function for every executor: a render job is a job file
(``OUT/.work/jobs/<id>.json``, a whole camera path and the sequences it feeds)
run by a render worker (``blendgen.pipeline.frameloop``, with an orphan guard) until the
job's ``sequences/.<id>.tmp/`` dirs are complete; the caller then commits them.

- ``local`` (default): ``workers`` processes at once on this machine; each gets
  ``threads`` Cycles threads so the cores are not oversubscribed.
- ``ray``: the same command inside a Ray task (``num_cpus=threads``) on any node
  of a cluster. OUT must be on a filesystem every node sees at the same path, and
  every node needs ``dockbench[render,ray]`` installed. Ray is imported only here,
  only when chosen.

Persistent workers (local): each slot keeps one ``python -m blendgen.pipeline.executor
--serve`` process that takes job after job (JSON lines on its stdin), so Python, bpy,
numpy/cv2 and pydantic are imported once per slot instead of once per job, and the Blender
scene is kept while consecutive jobs share it (rebuilt from factory settings otherwise).
A worker is replaced after a failed job and when its resident memory passed
``RECYCLE_MB`` after a job (Blender leaks across renders). Ray tasks and calibration
renders run one fresh ``python -m blendgen.pipeline.executor JOB.json`` per job.

Stopping: on Ctrl-C (KeyboardInterrupt) or SIGTERM the running workers are
killed and no new ones start; a render failure lets the running jobs finish
(their sequences are committed) and starts no new one. A worker whose parent
dies (kill -9, a Ray worker killed) notices within a second and exits, so
nothing keeps writing into a dataset that a re-run is resuming.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import contextmanager
from pathlib import Path

from blendgen.config.models import ConfigError

EXECUTORS = ("local", "ray")
PARENT_ENV = "DOCKBENCH_PARENT_PID"
RAY_THREADS = 2  # Cycles threads (= Ray CPUs) per job on a cluster: one job per core pair


class RenderError(RuntimeError):
    """A worker process failed; the message carries the tail of its log."""


class _Stopped(RenderError):
    """A job not started because the run is stopping."""


class WorkerCrashed(RenderError):
    """A persistent worker died without answering (a signal, the OOM killer, a crash in
    Blender): the job is run once more in a fresh worker before it is reported."""


class ExecutorError(ConfigError):
    """A user error choosing the executor (unknown name, ray not installed): exit code 2."""


def default_workers(n_jobs: int) -> int:
    """Processes to run at once: one per core, at most one per job. Cycles scales over
    threads, but the per-frame image-space work (water, particles, PNG) is one thread
    per sequence: measured on 2 cores, 2 workers x 1 thread render the same as
    1 x 2 and post-process 1.7x faster (the paper suite: 2.8 vs 1.6 frames/s)."""
    return max(1, min(n_jobs, os.cpu_count() or 1))


def threads_per_worker(workers: int) -> int:
    return max(1, (os.cpu_count() or 1) // workers)


def slots(kind: str, n_jobs: int, workers: int | None, threads: int = 0) -> tuple[int | None, int]:
    """(jobs at once, Cycles threads per job) for executor ``kind``.

    ``threads`` is ``render.threads`` of the config (0 = automatic). For Ray,
    ``workers`` caps the tasks in flight (None: Ray schedules by CPUs)."""
    if kind == "ray":
        return workers, threads or min(RAY_THREADS, os.cpu_count() or 1)
    n = workers or default_workers(n_jobs)
    return n, threads or threads_per_worker(n)


# -- the job function: one worker process --------------------------------------
def worker_command(job_file: Path) -> list[str]:
    """Command line of a dataset render worker for ``job_file``."""
    return [sys.executable, "-m", "blendgen.pipeline.executor", str(job_file)]


def calibration_command(job_file: Path) -> list[str]:
    """Command line of a chessboard calibration render worker for ``job_file``."""
    return [sys.executable, "-m", "blendgen.pipeline.executor", "--calibration", str(job_file)]


def require_render_stack() -> None:
    """Raise ExecutorError (a user error) when bpy is not installed, before any worker starts."""
    import importlib.util

    if importlib.util.find_spec("bpy") is None:
        raise ExecutorError(
            "rendering needs Blender as a module: pip install 'dockbench[render]' "
            f"(bpy 5.2, Python 3.13; this is Python {sys.version_info.major}."
            f"{sys.version_info.minor}); evaluation works without it"
        )


class Children:
    """Worker processes started by this process; ``kill()`` ends them and blocks new ones."""

    def __init__(self):
        self._lock = threading.Lock()
        self._procs: set[subprocess.Popen] = set()
        self.closed = False

    def spawn(self, cmd: list[str], log, stdin=subprocess.DEVNULL, stdout=None) -> subprocess.Popen:
        with self._lock:
            if self.closed:
                raise _Stopped("stopped: no new render jobs")
            env = {**os.environ, PARENT_ENV: str(os.getpid())}
            p = subprocess.Popen(cmd, stdout=log if stdout is None else stdout, stderr=log, stdin=stdin, env=env)
            self._procs.add(p)
            return p

    def forget(self, p: subprocess.Popen) -> None:
        with self._lock:
            self._procs.discard(p)

    def close(self) -> None:
        with self._lock:
            self.closed = True

    def kill(self, grace_s: float = 2.0) -> None:
        """SIGTERM every live worker, SIGKILL those still alive after ``grace_s``; reap all."""
        with self._lock:
            self.closed = True
            procs = list(self._procs)
        for p in procs:
            _terminate(p, grace_s)


def _terminate(p: subprocess.Popen, grace_s: float = 2.0) -> None:
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(grace_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def run_worker(
    job_file: Path,
    log_file: Path,
    children: Children | None = None,
    command: Callable[[Path], list[str]] = worker_command,
) -> None:
    """Run one render job to completion; raise RenderError with the log tail on failure.

    If this call is interrupted (KeyboardInterrupt, Ray cancel), the worker is killed."""
    children = children or Children()
    with open(log_file, "ab") as log:
        p = children.spawn(command(Path(job_file)), log)
        try:
            rc = p.wait()
        finally:
            _terminate(p)
            children.forget(p)
    if rc != 0:
        tail = Path(log_file).read_text(errors="replace").splitlines()[-25:]
        raise RenderError(f"render worker failed (exit {rc}) for {Path(job_file).name}:\n" + "\n".join(tail))


# -- persistent workers ------------------------------------------------------------
def serve_command(log_dir: Path) -> list[str]:
    """Command line of a persistent render worker; ``log_dir`` (the dataset's
    ``.work/logs``) only names in ``ps`` which dataset the worker serves."""
    return [sys.executable, "-m", "blendgen.pipeline.executor", "--serve", str(log_dir)]


RECYCLE_MB = 2048  # a worker whose resident memory passed this after a job is replaced


class PersistentWorker:
    """One long-lived render worker (``executor --serve``) taking job after job.

    bpy is imported once and the Blender scene is kept while consecutive jobs share it
    (``frameloop.serve``). Started lazily; replaced after a failed job or when its
    memory passed ``RECYCLE_MB`` (Blender leaks across renders). A job is done only when
    the worker replied ok: a killed or crashed worker raises RenderError with the job's
    log tail, exactly as a one-shot worker's non-zero exit does."""

    def __init__(self, children: Children, log_dir: Path, name: str):
        self.children, self.log_dir, self.name = children, log_dir, name
        self.proc: subprocess.Popen | None = None

    def _start(self) -> subprocess.Popen:
        with open(self.log_dir / f"{self.name}.log", "ab") as log:  # startup errors (before any job)
            p = self.children.spawn(serve_command(self.log_dir), log, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        return p

    def run(self, job_file: Path, log_file: Path) -> None:
        """Run one job to completion; raise RenderError with the log tail on failure."""
        if self.proc is None or self.proc.poll() is not None:
            self.close()
            self.proc = self._start()
        p = self.proc
        try:
            p.stdin.write((json.dumps({"job": str(job_file), "log": str(log_file)}) + "\n").encode())
            p.stdin.flush()
            line = p.stdout.readline()
        except (BrokenPipeError, ValueError, OSError):
            line = b""
        reply = json.loads(line) if line.strip() else None
        if reply is None or not reply.get("ok") or reply.get("rss_mb", 0) > RECYCLE_MB:
            self.close()
        if reply is None or not reply.get("ok"):
            what = reply["error"] if reply else f"worker exited (code {p.returncode})"
            tail = Path(log_file).read_text(errors="replace").splitlines()[-25:] if Path(log_file).exists() else []
            kind = RenderError if reply else WorkerCrashed
            raise kind(f"render worker failed ({what}) for {Path(job_file).name}:\n" + "\n".join(tail))

    def close(self) -> None:
        """End the worker (EOF on its stdin, then SIGTERM/SIGKILL) and reap it."""
        p, self.proc = self.proc, None
        if p is None:
            return
        try:
            p.stdin.close()
            p.wait(5.0)
        except (OSError, ValueError, subprocess.TimeoutExpired):
            pass
        _terminate(p)
        p.stdout.close()
        self.children.forget(p)


def _run_slots(
    job_files: list[Path],
    log_dir: Path,
    workers: int,
    on_done: Callable[[Path], None],
    children: Children,
    errors: list,
) -> None:
    """``workers`` threads, each with one PersistentWorker, take jobs in order from one queue;
    after the first error no thread takes a new job (the running ones finish)."""
    queue = list(job_files)
    lock = threading.Lock()

    def slot(i: int):
        w = PersistentWorker(children, log_dir, f"worker-{i}")
        try:
            while True:
                with lock:
                    if errors or children.closed or not queue:
                        return
                    jf = queue.pop(0)
                try:
                    try:
                        w.run(jf, log_dir / f"{jf.stem}.log")
                    except WorkerCrashed:
                        if children.closed:  # killed because the run is stopping
                            raise
                        w.run(jf, log_dir / f"{jf.stem}.log")  # once more, in a fresh worker
                    on_done(jf)
                except _Stopped:
                    return
                except BaseException as e:
                    children.close()
                    errors.append(e)
                    return
        finally:
            w.close()

    threads = [
        threading.Thread(target=slot, args=(i,), daemon=True, name=f"render-slot-{i}")
        for i in range(min(workers, len(queue)))
    ]
    for t in threads:
        t.start()
    try:
        for t in threads:
            while t.is_alive():
                t.join(0.5)
    except BaseException:
        children.kill()
        for t in threads:
            t.join()
        raise
    if errors:
        raise errors[0]


# -- local process pool ----------------------------------------------------------
def run_local(
    job_files: list[Path],
    log_dir: Path,
    workers: int,
    on_done: Callable[[Path], None],
    command: Callable[[Path], list[str]] | None = None,
) -> None:
    """Run job files on a local process pool; ``on_done(job_file)`` after each success.

    Without ``command``: ``workers`` persistent render workers (PersistentWorker), each
    taking job after job; with ``command``: one fresh process per job. The first failure
    is raised after the running jobs finish (no new ones start); an interrupt kills the
    running workers at once."""
    children = Children()
    errors: list[BaseException] = []  # in the order they happened
    if command is None:
        _run_slots(job_files, log_dir, workers, on_done, children, errors)
        return

    def one(jf: Path):
        try:
            run_worker(jf, log_dir / f"{jf.stem}.log", children, command)
            on_done(jf)
        except _Stopped:
            pass
        except BaseException as e:
            children.close()  # before this thread can take the next job
            errors.append(e)

    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        futs = [pool.submit(one, jf) for jf in job_files]
        pending = set(futs)
        while pending and not errors:
            _, pending = wait(pending, timeout=0.5)
        if errors:
            for f in futs:
                f.cancel()
            pool.shutdown(wait=True)  # the running jobs finish (and are committed)
            raise errors[0]
    except BaseException:
        children.kill()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


# -- Ray -------------------------------------------------------------------------
def require_ray():
    """Import ray or raise ExecutorError (a user error) saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ExecutorError(
            "executor 'ray' needs Ray: pip install 'dockbench[ray]' (or pip install ray), or use --executor local"
        ) from None
    return ray


def _ray_job(job_file: str, log_file: str) -> str:
    """Ray task body: the local job function, on whichever node Ray picked."""
    if not Path(job_file).is_file():
        import socket

        raise RenderError(
            f"{job_file} is not visible on Ray node {socket.gethostname()}: the output "
            "directory must be on a filesystem shared by every node at the same path"
        )
    run_worker(Path(job_file), Path(log_file))
    return job_file


@contextmanager
def ray_session(address: str | None):
    """Connect to the cluster at ``address`` (``auto``, ``host:port``, ``ray://host:10001``),
    start a local Ray instance when None, or reuse an already initialized one."""
    ray = require_ray()
    started = False
    if not ray.is_initialized():
        kw = dict(log_to_driver=False, logging_level=logging.WARNING)
        if address is None:  # a new private instance, even if `ray start` ran here
            kw.update(num_cpus=os.cpu_count() or 1, include_dashboard=False)
        else:
            check_ray_address(address)
        try:
            ray.init(address=address or "local", **kw)
        except (ConnectionError, ValueError, RuntimeError) as e:
            hint = (
                "; a cluster with token authentication (Ray >= 2.59 default) needs "
                "RAY_AUTH_MODE=token and its token (RAY_AUTH_TOKEN or ~/.ray/auth_token)"
            )
            raise ExecutorError(f"cannot connect to Ray at {address!r}: {e}{hint if address else ''}") from None
        started = True
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def check_ray_address(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast on a ``host:port`` / ``ray://host:port`` nobody listens on (Ray itself
    retries for minutes); ``auto`` and other forms are left to Ray."""
    import socket

    hostport = address.removeprefix("ray://")
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit() or not host:
        return
    try:
        conn = socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s)
    except OSError as e:
        raise ExecutorError(
            f"no Ray cluster answers at {address!r} ({e}); start one with `ray start --head` or check --address"
        ) from None
    with conn:
        if not os.environ.get("RAY_USE_TLS") and not _speaks_grpc(conn, timeout_s):
            raise ExecutorError(
                f"{address!r} answers but is not a Ray cluster (no gRPC reply; Ray would retry "
                "for minutes); check --address: the head's GCS port (6379) or ray://host:10001"
            )


def _speaks_grpc(conn, timeout_s: float) -> bool:
    """True when the peer answers the HTTP/2 connection preface with a SETTINGS frame, as Ray's
    GCS and client servers (gRPC over cleartext HTTP/2, RFC 9113 section 3.4) do at once."""
    try:
        conn.sendall(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]))
        conn.settimeout(timeout_s)
        head = b""
        while len(head) < 9:
            chunk = conn.recv(9 - len(head))
            if not chunk:
                break
            head += chunk
    except (TimeoutError, OSError):
        return False
    return len(head) == 9 and head[3] == 4


def run_ray(
    job_files: list[Path],
    log_dir: Path,
    on_done: Callable[[Path], None],
    address: str | None = None,
    threads: int = RAY_THREADS,
    max_in_flight: int | None = None,
) -> None:
    """Run job files as Ray tasks (``num_cpus=threads`` each); ``on_done`` on the driver.

    Tasks lost with a node are retried (the job rewrites its temp dirs from scratch);
    a render failure is raised after the tasks in flight finish; an interrupt cancels them."""
    with ray_session(address) as ray:
        task = ray.remote(num_cpus=threads, max_retries=2)(_ray_job)
        queue = list(job_files)
        limit = max_in_flight or len(queue)
        in_flight: dict = {}
        error = None
        try:
            while in_flight or (queue and error is None):
                while queue and error is None and len(in_flight) < limit:
                    jf = queue.pop(0)
                    in_flight[task.remote(str(jf), str(log_dir / f"{jf.stem}.log"))] = jf
                done, _ = ray.wait(list(in_flight), num_returns=1, timeout=0.5)
                for ref in done:
                    jf = in_flight.pop(ref)
                    try:
                        ray.get(ref)
                    except ray.exceptions.RayError as e:
                        error = error or RenderError(f"Ray task for {jf.name} failed: {_ray_cause(e)}")
                        continue
                    on_done(jf)
            if error is not None:
                raise error
        except BaseException:
            for ref in in_flight:
                ray.cancel(ref)
            raise


def _ray_cause(e: Exception) -> str:
    cause = getattr(e, "cause", None)
    return str(cause) if cause is not None else str(e).splitlines()[-1]


# -- progress, job files, signals --------------------------------------------------
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
        sys.stderr.write(
            f"{self.label}: {done}/{self.total} frames ({100 * done / max(self.total, 1):.0f}%)"
            f" {rate:.1f} frames/s, eta {eta:.0f} s   {end}"
        )
        sys.stderr.flush()


def write_job(job, path: Path) -> Path:
    """Write a job record (``plan.JobRecord``; a plain dict is written as JSON as is)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(job.model_dump_json() if hasattr(job, "model_dump_json") else json.dumps(job))
    return path


@contextmanager
def sigterm_as_interrupt():
    """Within the block (main thread only), SIGTERM raises KeyboardInterrupt so the
    workers are killed and the finished sequences kept, as on Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _exit_with_parent(parent_pid: int, period_s: float = 0.5) -> None:
    """In a worker: exit as soon as the process that started it is gone (re-parented)."""

    def watch():
        while True:
            if os.getppid() != parent_pid:
                os._exit(137)
            time.sleep(period_s)

    threading.Thread(target=watch, daemon=True, name="orphan-guard").start()


def _child_main(argv: list[str]) -> int:
    parent = os.environ.get(PARENT_ENV)
    if parent:
        _exit_with_parent(int(parent))
    from blendgen.pipeline import allocator

    allocator.keep_heap()  # per-frame image arrays reuse heap pages
    allocator.one_thread_per_process()  # one worker per core: no BLAS or OpenCV pools spinning
    if len(argv) > 1 and argv[1] == "--serve":
        from blendgen.pipeline import frameloop

        return frameloop.serve_main()
    if len(argv) > 2 and argv[1] == "--calibration":
        from blendgen.blender import calibration_scene

        return calibration_scene.main([argv[0], argv[2]])
    from blendgen.pipeline import frameloop

    return frameloop.main(argv)


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv))
