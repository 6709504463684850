"""Object models of a BOP export: closed box meshes with normals, origin at the bounding-box centre.

BOP's own models have their origin at the centre of the model's 3D bounding box and carry
vertex normals (BOP format documentation, ``docs/bop_datasets_format.md`` of the toolkit:
"models_info.json ... the origin of the model coordinate system is at the centre of the 3D
bounding box"); ``models_eval`` holds the same surfaces resampled with a denser, roughly
uniform set of vertices, on which the toolkit computes MSSD and MSPD and renders VSD.

dockbench's markers are boxes (:func:`evalkit.metrics.recall.marker_model`: a plate 5 mm deep,
or one cube per LED). Here each box face becomes its own 4 vertices with the face's outward
normal (24 vertices per box, so flat shading is right), expressed in mm about the centre ``c``
of the marker model's bounding box; a GT pose ``(R, t)`` of the marker frame becomes
``(R, t + R c)`` for the model frame. ``models_eval`` subdivides every face into a grid of
at most :data:`EVAL_STEP_MM` spacing. A rigid motion's largest displacement over a convex set
is reached at a corner, so MSSD is the same on either mesh; the grid samples the surface as
the toolkit's resampled models do.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evalkit.metrics.recall import marker_model

EVAL_STEP_MM = 5.0
# the 6 faces of a recall._box (8 vertices: the z1 face TL, TR, BR, BL, then the z0 face),
# each as 4 corner indices
_BOX_QUADS = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])


@dataclass(frozen=True)
class ObjectModel:
    """One marker as a BOP object: ``boxes`` ``(k, 8, 3)`` mm in the marker frame, ``centre_mm``
    ``(3,)`` the bounding-box centre (the BOP model origin) in the marker frame."""

    boxes: np.ndarray
    centre_mm: np.ndarray

    @classmethod
    def from_marker(cls, marker: dict) -> ObjectModel:
        vertices, _ = marker_model(marker)
        v = vertices * 1000.0
        return cls(v.reshape(-1, 8, 3), (v.min(axis=0) + v.max(axis=0)) / 2.0)

    def pose_m2c(self, T_cam_marker: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t_mm)`` of the model frame from a marker pose ``T_cam_marker`` (4x4, m)."""
        R = np.asarray(T_cam_marker, float)[:3, :3]
        return R, np.asarray(T_cam_marker, float)[:3, 3] * 1000.0 + R @ self.centre_mm

    def mesh(self, step_mm: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(vertices (N, 3) mm, normals (N, 3), faces (F, 3))`` about the model origin; each box
        face a grid of at most ``step_mm`` spacing (None: its 4 corners only)."""
        verts: list[np.ndarray] = []
        norms: list[np.ndarray] = []
        faces: list[np.ndarray] = []
        for box in self.boxes - self.centre_mm:
            middle = box.mean(axis=0)
            for quad in _BOX_QUADS:
                v, f = _grid(box[quad], step_mm)
                n = np.cross(box[quad[1]] - box[quad[0]], box[quad[3]] - box[quad[0]])
                n = n / np.linalg.norm(n)  # the grid's triangles turn this way
                if n @ (box[quad].mean(axis=0) - middle) < 0:
                    n, f = -n, f[:, ::-1]  # outward, counter-clockwise
                faces.append(f + sum(len(x) for x in verts))
                verts.append(v)
                norms.append(np.tile(n, (len(v), 1)))
        return np.vstack(verts), np.vstack(norms), np.vstack(faces)

    def info(self) -> dict:
        """models_info.json entry: diameter, min_*, size_* (mm)."""
        v = (self.boxes - self.centre_mm).reshape(-1, 3)
        lo, hi = v.min(axis=0), v.max(axis=0)
        diam = float(np.max(np.linalg.norm(v[:, None] - v[None], axis=2)))
        return {
            "diameter": diam,
            "min_x": float(lo[0]),
            "min_y": float(lo[1]),
            "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]),
            "size_y": float(hi[1] - lo[1]),
            "size_z": float(hi[2] - lo[2]),
        }


def _grid(quad: np.ndarray, step_mm: float | None) -> tuple[np.ndarray, np.ndarray]:
    """A planar quad (4, 3) (corners in order) as a ``(n+1) x (m+1)`` vertex grid and its triangles."""
    a, b, d = quad[0], quad[1], quad[3]
    n = 1 if step_mm is None else max(1, int(np.ceil(np.linalg.norm(b - a) / step_mm)))
    m = 1 if step_mm is None else max(1, int(np.ceil(np.linalg.norm(d - a) / step_mm)))
    s, r = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, m + 1))
    v = a + s.reshape(-1, 1) * (b - a) + r.reshape(-1, 1) * (d - a)
    i = np.arange((m + 1) * (n + 1)).reshape(m + 1, n + 1)
    p, q, w, x = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    return v, np.vstack([np.c_[p, q, w], np.c_[p, w, x]])


def write_ply(path: Path, vertices_mm: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> None:
    """ASCII PLY of a triangle mesh with vertex normals (mm)."""
    head = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(vertices_mm)}",
        "property float x",
        "property float y",
        "property float z",
        "property float nx",
        "property float ny",
        "property float nz",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    rows = [
        " ".join(f"{c:.6f}" for c in p) + " " + " ".join(f"{c:.6f}" for c in n) for p, n in zip(vertices_mm, normals)
    ]
    rows += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    path.write_text("\n".join(head + rows) + "\n")
