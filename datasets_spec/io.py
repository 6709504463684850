"""Save/load pairs and hashing of the dataset format (FORMAT.md, spec_version 1.2; reads 1.0 and 1.1).

One place reads and writes each file of a dataset: the generator writes through
:func:`save_json_atomic`, :func:`append_frame`, :func:`save_image`, :func:`save_range`
and :func:`save_index`; readers use :func:`load_manifest`, :func:`iter_frames`,
:func:`load_range` and :func:`load_index`; both hash with :func:`sha256_file` and
:func:`content_hash`.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator
from importlib import resources
from pathlib import Path
from typing import IO

from datasets_spec.validate import (
    MAX_JSON_LINE_BYTES,
    MAX_MANIFEST_BYTES,
    RELPATH,
    RELPATH_RULE,
    ContentError,
    camera_problem,
    check_frame_record,
    image_problem,
    load_schema,
    loads_bounded,
    non_finite_key,
    png_header,
    schema_message,
)

FORMAT_NAME = "dockbench-dataset"
SPEC_VERSION = "1.2"
#: 1.0: range as float32 NPZ, passes per sequence; 1.1: no sequences[].end
SUPPORTED_SPEC_VERSIONS = ("1.0", "1.1", SPEC_VERSION)
#: How a sequence's camera path ends (manifest ``sequences[].end``, 1.2; FORMAT.md): its own end,
#: the camera at the dock's marker plane, or the face of the water the vehicle's hull touched.
SEQUENCE_ENDS = ("path", "dock", "pool_wall", "pool_floor", "seabed")
#: The ends where the hull touched the water's boundary (a current carried it there).
BOUNDARY_ENDS = SEQUENCE_ENDS[2:]
MANIFEST = "manifest.json"
FRAMES = "frames.jsonl"
DEFAULT_D_MIN_REL_M = 0.2
RENDERS = "renders"  # 1.1: passes of one render, shared by every sequence it feeds
RANGE_UNIT_M = 0.001  # 1.1 range PNG: one uint16 unit = 1 mm
RANGE_MAX_UNITS = 65534  # largest stored range (65.534 m); 0 = no surface or farther
PNG_FAST = 1  # zlib level of written PNGs (measured: level 1 costs 5 ms, 71 kB
# per 640x480 range map; level 6 18 ms, 42 kB)
# One PNG row filter (Up) instead of libpng's per-row trial of all five: the trial, not zlib,
# costs most of an encode (level 0 takes as long as level 1). Measured with cv2.imencode at
# level 1 on suite frames (640x480): camera image 4.97 -> 1.56 ms, 9 kB either way; range map
# 5.41 -> 2.72 ms, 71 -> 64 kB.


def png_params() -> list[int]:
    """cv2.imwrite parameters of every PNG the dataset writes (zlib level, one row filter)."""
    import cv2

    return [cv2.IMWRITE_PNG_COMPRESSION, PNG_FAST, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]


class DatasetError(Exception):
    """A dataset is missing, malformed or of an unsupported version."""


# -- hashing ---------------------------------------------------------------
def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def content_hash(files: dict[str, str]) -> str:
    """sha256 over the sorted ``files`` entries as ``"path sha256\\n"`` lines (FORMAT.md)."""
    blob = "".join(f"{p} {files[p]}\n" for p in sorted(files))
    return hashlib.sha256(blob.encode()).hexdigest()


PIXELS_TAG = "dockbench-pixels-1"


def pixel_sha256(pixels) -> str:
    """Hex sha256 of a decoded image: ``"dockbench-pixels-1 <dtype> <HxWxC>\\n"`` then its
    C-order bytes. An image a streaming run never encoded (``stream.json`` ``pixels``) is
    checked this way against the PNG a later ``generate`` writes, once that PNG is decoded
    (camera image: HxWx3 uint8 RGB, as :meth:`evalkit.dataset.Dataset.load_image` returns)."""
    import numpy as np

    a = np.ascontiguousarray(pixels)
    h = hashlib.sha256(f"{PIXELS_TAG} {a.dtype.str} {'x'.join(map(str, a.shape))}\n".encode())
    h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def raw_image_path(png: Path) -> Path:
    """Where a streaming run leaves the raw pixels of a camera image it does not keep:
    ``rgb/.<i>.npy`` beside the absent ``rgb/<i>.png`` (a dot-name: never part of a dataset)."""
    png = Path(png)
    return png.with_name(f".{png.stem}.npy")


def save_raw_image(png: Path, rgb) -> None:
    """(H,W,3) uint8 RGB as raw ``.npy`` at :func:`raw_image_path` (no PNG encode: ~0.3 ms
    instead of ~1.6 ms at 640x480; deleted once evaluated)."""
    import numpy as np

    path = raw_image_path(png)
    with open(path, "wb") as fh:
        np.save(fh, np.ascontiguousarray(rgb), allow_pickle=False)


def load_raw_image(path: Path, height: int, width: int):
    """The (H,W,3) uint8 RGB written by :func:`save_raw_image`; DatasetError if it is not one."""
    import numpy as np

    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: unreadable raw image ({exc})") from None
    if a.dtype != np.uint8 or a.shape != (height, width, 3):
        raise DatasetError(f"{path}: raw image must be {height}x{width}x3 uint8, got {a.dtype} {a.shape}")
    return a


def dataset_files(root: Path) -> list[str]:
    """Relative paths of every dataset file, sorted, without manifest.json and without
    dot-names (work files and partial ``.tmp`` sequences are not part of a dataset)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for f in filenames:
            rel = Path(dirpath, f).relative_to(root).as_posix()
            if not f.startswith(".") and rel != MANIFEST:
                out.append(rel)
    return sorted(out)


# -- paths -----------------------------------------------------------------
def path_inside(root: Path, rel: str | Path, what: str = "path") -> Path:
    """``root / rel`` resolved (symlinks followed), proven to lie inside ``root``.

    Raises :class:`DatasetError` for an absolute ``rel``, ``..`` that climbs out, or a
    symlink (at any level) that leads outside ``root`` -- the writer calls it before it
    creates a file, the reader before it opens one."""
    base = Path(root).resolve()
    rel_s = str(rel)
    if "\x00" in rel_s:
        raise DatasetError(f"{root}: {what} {rel_s!r} contains a NUL byte")
    target = (base / rel_s).resolve()
    if Path(rel_s).is_absolute() or os.path.commonpath([base, target]) != str(base):
        raise DatasetError(
            f"{Path(root) / rel_s}: {what} {rel_s!r} resolves to {target}, outside the "
            f"dataset folder {base}; allowed: a relative path inside it (no '..', "
            "no symlink leaving it)"
        )
    return target


# -- schemas ---------------------------------------------------------------
def doc_path(name: str) -> Path:
    """Filesystem path of a bundled document (``FORMAT.md``, ``LOCALIZER_PROTOCOL.md``)."""
    return Path(str(resources.files("datasets_spec").joinpath(name)))


def check_schema(obj: dict, schema_name: str, where: str) -> None:
    """Validate ``obj`` against a bundled schema; the first problem names its key path."""
    import jsonschema

    validator = jsonschema.Draft202012Validator(load_schema(schema_name))
    err = jsonschema.exceptions.best_match(validator.iter_errors(obj))
    if err is not None:
        key = ".".join(str(p) for p in err.absolute_path) or "<root>"
        message = err.message
        if err.validator == "pattern" and err.validator_value == RELPATH.pattern:
            message = f"{err.instance!r} {RELPATH_RULE}"
        elif err.validator == "propertyNames":
            key = f"{key} (a key)"
        raise DatasetError(f"{where}: {key}: {message}")


# -- manifest.json ---------------------------------------------------------
def save_json_atomic(path: Path, obj) -> None:
    """Write JSON via a temp file in the same directory and an atomic rename."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=1, sort_keys=False) + "\n")
    os.replace(tmp, path)


def _read_regular(root: Path, rel: str, what: str, max_bytes: int) -> bytes:
    """Bytes of ``root/rel``: proven inside ``root``, a regular file, at most ``max_bytes``."""
    import stat

    path = path_inside(root, rel, what)
    st = path.stat()
    if not stat.S_ISREG(st.st_mode):
        raise DatasetError(f"{Path(root) / rel}: {what} is not a regular file")
    if st.st_size > max_bytes:
        raise DatasetError(
            f"{Path(root) / rel}: {what} is {st.st_size / 2**20:.0f} MiB; allowed: up to {max_bytes >> 20} MiB"
        )
    with open(path, "rb") as fh:
        return fh.read(max_bytes + 1)


def load_manifest(root: Path) -> dict:
    """Load ``root/manifest.json`` and validate it (format, version, schema, camera)."""
    path = Path(root) / MANIFEST
    if not Path(root).is_dir():
        raise DatasetError(f"{root}: not a directory")
    if not path.is_file():
        raise DatasetError(f"{path}: missing manifest (dataset incomplete or not a dockbench dataset)")
    try:
        manifest = loads_bounded(_read_regular(Path(root), MANIFEST, "manifest", MAX_MANIFEST_BYTES).decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: invalid JSON: not UTF-8 ({exc.reason} at byte {exc.start})") from None
    except ContentError as exc:
        raise DatasetError(f"{path}: invalid JSON: {exc}") from None
    if not isinstance(manifest, dict):
        raise DatasetError(f"{path}: top level must be a JSON object")
    if manifest.get("format") != FORMAT_NAME:
        raise DatasetError(f'{path}: "format" is {manifest.get("format")!r}, expected {FORMAT_NAME!r}')
    version = manifest.get("spec_version")
    if version not in SUPPORTED_SPEC_VERSIONS:
        raise DatasetError(
            f'{path}: unsupported "spec_version" {version!r}; supported: {", ".join(SUPPORTED_SPEC_VERSIONS)}'
        )
    for key in ("camera", "sequences"):
        if key not in manifest:
            raise DatasetError(f"{path}: missing key {key!r}")
    check_schema(manifest, "manifest.schema.json", str(path))
    if manifest["sequences"] == []:
        raise DatasetError(
            f'{path}: "sequences" is empty (a dataset holds at least one sequence); nothing to evaluate or export'
        )
    problem = camera_problem(manifest["camera"])
    bad = non_finite_key(manifest)
    if bad and not problem:
        problem = f"{bad}: non-finite number (allowed: finite numbers only)"
    if problem:
        raise DatasetError(f"{path}: {problem}")
    return manifest


# -- per-frame files -------------------------------------------------------
def _imwrite(path: Path, img, what: str) -> None:
    import cv2

    if not cv2.imwrite(str(path), img, png_params()):
        raise OSError(f"{path}: could not write the {what} PNG")


def _imread(path: Path, flags: int | None = None):
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED if flags is None else flags)
    if img is None:
        raise DatasetError(f"{path}: missing or unreadable image")
    return img


def save_image(path: Path, rgb) -> None:
    """The camera image (H,W,3) uint8 RGB as an 8-bit sRGB PNG."""
    import cv2

    _imwrite(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), "image")


def range_to_units(range_m):
    """Range (H,W) metres (inf/NaN = no surface) -> (H,W) uint16 millimetres of the 1.1 range PNG:
    ``round(range_m / 0.001)``; 0 for no surface, non-finite, < 0.5 mm or beyond 65.534 m."""
    import numpy as np

    r = np.asarray(range_m, dtype=np.float64)
    units = np.rint(np.where(np.isfinite(r), r, 0.0) / RANGE_UNIT_M)
    units[(units < 1) | (units > RANGE_MAX_UNITS)] = 0
    return units.astype(np.uint16)


def save_range(path: Path, range_m) -> None:
    """Range along each pixel ray, (H,W) metres, as a uint16 millimetre PNG (FORMAT.md 1.1):
    error at most 0.5 mm up to 65.534 m; farther or no surface is stored as 0 (read back as inf)."""
    _imwrite(Path(path), range_to_units(range_m), "range")


def load_range(path: Path):
    """(H,W) float32 range in metres along each ray, inf = no surface. Reads the 1.1 uint16
    millimetre PNG and the 1.0 ``range_m`` float32 NPZ."""
    import numpy as np

    path = Path(path)
    if path.suffix == ".npz":
        try:
            with np.load(path) as z:
                return np.asarray(z["range_m"], dtype=np.float32)
        except (OSError, KeyError, ValueError) as exc:
            raise DatasetError(f"{path}: unreadable range NPZ ({exc})") from None
    units = _imread(path)
    if units.dtype != np.uint16 or units.ndim != 2:
        raise DatasetError(f"{path}: range PNG must be one-channel uint16, got {units.dtype} {units.shape}")
    out = units.astype(np.float32) * np.float32(RANGE_UNIT_M)
    out[units == 0] = np.inf
    return out


def save_index(path: Path, index) -> None:
    """Object-index pass (H,W) uint8 as a one-channel PNG."""
    _imwrite(Path(path), index, "object-index")


def load_index(path: Path):
    """(H,W) uint8 object index of a frame (values are the manifest's ``object_index`` keys)."""
    return _imread(Path(path))


def render_dir_name(render_key: str) -> str:
    """Relative directory of one render's shared passes: ``renders/<first 16 hex of its key>``."""
    return f"{RENDERS}/{render_key[:16]}"


# -- frames.jsonl ----------------------------------------------------------
def append_frame(fh: IO[str], frame: dict) -> None:
    """Append one frame record as a JSON line (the generator's only way to write frames)."""
    fh.write(json.dumps(frame) + "\n")


def check_frame(frame: dict, where: str) -> None:
    """The record must follow frame.schema.json (paths, shapes, finite numbers)."""
    try:
        check_frame_record(frame)
    except ContentError as exc:
        # the rule in words (key, what is allowed); jsonschema's own wording is added when
        # it says more than a regular expression
        detail = schema_message(frame)
        extra = f" [schema: {detail}]" if detail and "does not match" not in detail else ""
        raise DatasetError(f"{where}: {exc}{extra}") from None


def _bounded_lines(fh: IO[bytes], path: Path) -> Iterator[tuple[int, bytes]]:
    """``(line number, line)`` of a binary file; a line over MAX_JSON_LINE_BYTES is an error
    (read at most that much: a line without end cannot fill the memory)."""
    lineno = 0
    while True:
        line = fh.readline(MAX_JSON_LINE_BYTES + 1)
        if not line:
            return
        lineno += 1
        if len(line) > MAX_JSON_LINE_BYTES:
            raise DatasetError(
                f"{path}:{lineno}: line longer than {MAX_JSON_LINE_BYTES >> 20} MiB "
                "(allowed: one frame record of a few kB per line)"
            )
        yield lineno, line


def iter_frames(path: Path, root: Path | None = None) -> Iterator[dict]:
    """Yield the frame records of one ``frames.jsonl`` in file order, each checked against
    frame.schema.json; frame indices must be unique. With ``root`` (the dataset folder)
    the file is proven to lie inside it (no symlink out, a regular file)."""
    import stat

    if root is not None:
        path_inside(root, os.path.relpath(path, root), "frames file")
    if not path.is_file():
        raise DatasetError(f"{path}: missing frames file")
    if not stat.S_ISREG(path.stat().st_mode):
        raise DatasetError(f"{path}: frames file is not a regular file")
    seen: dict[int, int] = {}
    with open(path, "rb") as f:
        for lineno, line in _bounded_lines(f, path):
            if not line.strip():
                continue
            try:
                frame = loads_bounded(line.decode("utf-8"))
            except UnicodeDecodeError:
                raise DatasetError(f"{path}:{lineno}: bad JSON line: not UTF-8") from None
            except ContentError as exc:
                raise DatasetError(f"{path}:{lineno}: bad JSON line: {exc}") from None
            if not isinstance(frame, dict):
                raise DatasetError(f"{path}:{lineno}: frame must be a JSON object")
            check_frame(frame, f"{path}:{lineno}")
            if frame["index"] in seen:
                raise DatasetError(
                    f"{path}:{lineno}: index: frame index {frame['index']} repeats line "
                    f"{seen[frame['index']]} (allowed: each index once per sequence)"
                )
            seen[frame["index"]] = lineno
            yield frame


def check_image_header(root: Path, frame: dict, camera: dict) -> Path:
    """The frame's image path, proven inside ``root``, whose PNG header (read without
    decoding) matches the manifest camera: width x height, 8-bit RGB. DatasetError otherwise."""
    path = path_inside(root, frame["image"], "image")
    shown = Path(root) / frame["image"]
    if not path.is_file():
        raise DatasetError(f"{shown}: missing image (frame {frame.get('index')!r})")
    try:
        problem = image_problem(png_header(path), int(camera["width"]), int(camera["height"]))
    except ContentError as exc:
        problem = str(exc)
    if problem:
        raise DatasetError(f"{shown}: {problem} (frame {frame.get('index')!r})")
    return path


def verify(root: Path) -> list[str]:
    """Check a dataset against its manifest; return human-readable problems ([] = OK).

    Reports: manifest errors, frame lines that break frame.schema.json (or repeat an
    index), paths leaving the dataset, images whose PNG header does not match the camera,
    files listed but missing, sha256 mismatches, files on disk not in the manifest
    (dot-named work files aside), and a wrong ``content_hash``.
    """
    root = Path(root)
    problems = []
    try:
        manifest = load_manifest(root)
        for seq in manifest["sequences"]:
            for frame in iter_frames(root / seq.get("path", f"sequences/{seq['id']}") / FRAMES, root):
                for key in ("image", "depth", "object_index"):
                    if key in frame:
                        path_inside(root, frame[key], key)
                if (root / frame["image"]).is_file():  # a missing one is reported below
                    try:
                        check_image_header(root, frame, manifest["camera"])
                    except DatasetError as exc:
                        problems.append(str(exc))
    except DatasetError as exc:
        return [str(exc)]
    files = manifest.get("files")
    if not isinstance(files, dict):
        return [f"{root / MANIFEST}: missing or invalid 'files' map"]
    for rel, digest in sorted(files.items()):
        try:
            fpath = path_inside(root, rel, "file")
        except DatasetError as exc:
            problems.append(str(exc))
            continue
        if not fpath.is_file():
            problems.append(f"{rel}: missing (listed in manifest)")
        elif sha256_file(fpath) != digest:
            problems.append(f"{rel}: sha256 mismatch")
    for rel in sorted(set(dataset_files(root)) - set(files)):
        problems.append(f"{rel}: extra file not in manifest")
    expected = manifest.get("content_hash")
    if expected is not None and expected != content_hash(files):
        problems.append(f"{MANIFEST}: content_hash does not match the 'files' entries")
    return problems
