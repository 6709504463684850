"""One frame's passes handed from the warm render server to its client as one raw file.

The closed loop renders a frame per control step in another process
(:mod:`blendgen.blender.serve`) and hands the passes over through a file in shared memory
(``/dev/shm``). An uncompressed ``.npz`` costs a zip container, a CRC-32 of every byte on
both sides and a copy on reading (measured, one 640x480 physical-mode frame of ``rgb``,
``albedo``, ``sun``, ``depth_z``, ``index``, 12.6 MB: ~11 CPU-ms to write, ~8 to read).
This file is a JSON header and the arrays' bytes, each 64-byte aligned:

- :func:`write_passes` writes it to ``PATH.tmp`` and renames it, so a reader never sees half
  a file and a file already mapped by a reader is never overwritten (a rename makes a new
  inode);
- :func:`read_passes` maps it copy-on-write: the arrays are views of the page cache, nothing
  is copied until a stage writes into an array (those pages become private to the reader;
  the file is never changed).

Layout: 8 bytes little-endian header length ``n``, ``n`` bytes of JSON
``{name: [dtype str, shape, byte offset]}``, then the data.
"""

from __future__ import annotations

import json
import mmap
import os

import numpy as np

ALIGN = 64  # bytes: each array starts on a cache line


def _aligned(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


def write_passes(path: str, passes: dict[str, np.ndarray]) -> None:
    """Write ``passes`` ({name: array}, any shapes and numeric dtypes) to ``path`` (atomic rename)."""
    arrays = {k: np.ascontiguousarray(v) for k, v in passes.items()}
    layout, offset = {}, 0
    for k, a in arrays.items():
        layout[k] = [a.dtype.str, list(a.shape), offset]
        offset = _aligned(offset + a.nbytes)
    head = json.dumps(layout).encode()
    start = _aligned(8 + len(head))
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        fh.write(len(head).to_bytes(8, "little") + head + bytes(start - 8 - len(head)))
        for k, a in arrays.items():
            pad = start + layout[k][2] - fh.tell()
            if pad:
                fh.write(bytes(pad))
            fh.write(a.reshape(-1).view(np.uint8).data)  # the array's bytes, no copy
    os.replace(tmp, path)


def read_passes(path: str) -> dict[str, np.ndarray]:
    """The arrays of a file written by :func:`write_passes`: writable views of a copy-on-write
    mapping (the file stays unchanged; the mapping lives as long as an array does)."""
    with open(path, "rb") as fh:
        n = int.from_bytes(fh.read(8), "little")
        layout = json.loads(fh.read(n))
        size = os.fstat(fh.fileno()).st_size
        mm = mmap.mmap(fh.fileno(), size, access=mmap.ACCESS_COPY) if size else None
    start = _aligned(8 + n)
    out = {}
    for k, (dtype, shape, offset) in layout.items():
        dt = np.dtype(dtype)
        count = int(np.prod(shape, dtype=np.int64))
        a = np.frombuffer(mm, dt, count, start + offset) if count else np.empty(0, dt)
        out[k] = a.reshape(shape)
    return out
