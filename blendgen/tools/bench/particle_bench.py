"""``bench particles``: cost of the fast particle path per frame (the <= 5 ms budget of docs/particles.md).

A synthetic frame (no Blender): the 15x5x8 m pool (600 m^3) filled with N particles, the
camera 1 m below the surface at one end looking down the pool's length, a wall at 15 m as
the range pass, a moving camera (1 m/s) and the paper config's lens; physical image formation
with the vehicle lamp on (the dearest case: the lamp's beam at every particle, depth factors per
pixel), and the paper config itself (``configs/paper_occlusion.yaml``: the article's image
formation, no lamp, uniform 5-20 mm). Times ``compose.add_particles`` (projection, culling,
light, blur, coverage, compositing): wall time and the process's CPU time (all threads: what
it costs the machine), median and minimum over frames after one warm-up; apart from it, the CPU
time of the drift to the next frame
(``SequenceState.advance``: random walk and periodic wrap of every particle in the pool, in
view or not), median, with the heap policy of the render workers (pipeline/allocator.py).
On a shared machine both are upper bounds; the minimum is the least disturbed frame.
"""

from __future__ import annotations

import math
import time

import numpy as np

from blendgen.config.models import Lamp, Lens, Water
from blendgen.geometry import intrinsics_from_hfov, make_T

POOL_MIN, POOL_MAX = [0.0, -2.5, -5.0], [15.0, 2.5, 3.0]  # 600 m^3, surface at z = 3


def _state(n: int, size_dist: str, lamp: bool, seed: int = 0, formation: str = "physical"):
    from blendgen.pipeline import compose
    from blendgen.pipeline.plan import OcclusionPost, SequencePost

    occ = OcclusionPost(
        n_total=n,
        count_dist="fixed",
        size_dist=size_dist,
        region_min=POOL_MIN,
        region_max=POOL_MAX,
        v_flow=[0.0, 0.0, 0.0],
    )
    post = SequencePost(
        seed=seed,
        fps=10.0,
        image_formation=formation,
        water=Water(preset="mild"),
        light_depth_m=1.0,
        surface_z_m=3.0,
        irradiance_w_m2=2.6,
        occlusion=occ,
        lamps=[Lamp(power_w=20.0)] if lamp else [],
        lens=Lens(focal_length_mm=4.0, f_number=2.8, focus_m=5.0),
        suns=[([0.0, -0.5, -0.866], 3.0)],
        ambient_w_m2_sr=2.6 / (4 * math.pi * 0.75),
    )
    return compose.SequenceState.start(post)


def run(
    n: int = 60000,
    width: int = 640,
    height: int = 480,
    frames: int = 10,
    size_dist: str = "power_law",
    lamp: bool = True,
    formation: str = "physical",
) -> dict:
    """Median / max ms per frame of add_particles and the number of particles drawn; ``formation``
    the image formation ("physical" or the article's, ``configs/paper_occlusion.yaml``'s)."""
    from blendgen.physics.particles.field import project_particles
    from blendgen.pipeline import allocator, compose

    allocator.keep_heap()  # as in the render workers (executor._child_main)
    allocator.one_thread_per_process()
    K = intrinsics_from_hfov(width, height, math.radians(60.0))
    R = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    st = _state(n, size_dist, lamp, formation=formation)
    passes = {
        "rgb": np.full((height, width, 3), 0.1, np.float32),
        "range_m": np.full((height, width), 14.0, np.float32),
        "index": np.zeros((height, width), np.int32),
    }
    times, cpu, drift = [], [], []
    for i in range(frames + 1):
        T = make_T(R, [0.5 + 0.1 * i, 0.0, 2.0])
        t0, c0 = time.perf_counter(), time.process_time()
        compose.add_particles(passes, st, K, T, t_s=0.1 * i)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        c0 = time.process_time()
        st.advance()  # the drift to the next frame: a per-frame cost too
        drift.append(time.process_time() - c0)
    p = project_particles(st.field, K, T, width, height)
    ms = np.array(times[1:]) * 1e3
    return {
        "n": n,
        "size_dist": size_dist,
        "lamp": lamp,
        "formation": formation,
        "size": f"{width}x{height}",
        "in_view": int(p.u.size),
        "subpixel": int(np.count_nonzero(p.a < 0.5)),
        "ms_median": float(np.median(ms)),
        "ms_max": float(ms.max()),
        "cpu_ms_median": float(np.median(cpu[1:]) * 1e3),
        "cpu_ms_min": float(np.min(cpu[1:]) * 1e3),
        "drift_cpu_ms_median": float(np.median(drift[1:]) * 1e3),
    }


def format_row(r: dict) -> str:
    return (
        f"N={r['n']:>6d} {r['size_dist']:9s} {r['formation']:8s} "
        f"lamp={'on ' if r['lamp'] else 'off'} {r['size']}: "
        f"{r['in_view']:>6d} in view ({r['subpixel']} sub-pixel)  add_particles median "
        f"{r['ms_median']:.1f} ms wall (max {r['ms_max']:.1f}), CPU {r['cpu_ms_median']:.1f} ms "
        f"(min {r['cpu_ms_min']:.1f}); drift to the next frame CPU {r['drift_cpu_ms_median']:.1f} ms"
    )
