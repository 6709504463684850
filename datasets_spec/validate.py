"""Checks of untrusted dataset content (a dataset may come from anyone): bounded JSON
parsing, frame records against frame.schema.json, camera sanity and PNG headers read
without decoding. Every problem is one line naming the file, the key and what is allowed.

The frame check is a hand-written mirror of ``frame.schema.json`` (about 50x faster than
jsonschema, which would add minutes to a 360k-frame dataset); when it finds a problem the
message comes from jsonschema itself, and tests/test_hostile.py checks the two agree.
"""

from __future__ import annotations

import json
import math
import re
import struct
import zlib
from pathlib import Path
from typing import Any

MAX_JSON_LINE_BYTES = 1 << 20  # one frames.jsonl record is ~2 kB
MAX_MANIFEST_BYTES = 256 << 20  # ~1.5 MB per 10k frames (the files map)
MAX_FRAME_INDEX = 2**31 - 1
MAX_IMAGE_SIDE = 65535
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_COLOR_TYPES = {0: "gray", 2: "RGB", 3: "palette", 4: "gray+alpha", 6: "RGBA"}
RELPATH = re.compile(r"^(?!/)(?!.*\\)(?!(.*/)?\.\.(/|$))[^\u0000]+$")  # frame.schema.json $defs.relpath
RELPATH_RULE = (
    "is not a relative path inside the dataset (allowed: '/' separators, no '..', no leading '/', no backslash, no NUL)"
)


class ContentError(ValueError):
    """Untrusted content broke a rule; the message names the key (the caller adds the file)."""


def loads_bounded(text: str | bytes) -> Any:
    """``json.loads`` that turns deep nesting into ContentError (NaN/Infinity parse; the
    key-level checks report them with their key, see :func:`non_finite_key`)."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ContentError("JSON nested too deeply (allowed: a few levels)") from None
    except json.JSONDecodeError as exc:
        raise ContentError(f"bad JSON: {exc.msg} at column {exc.colno}") from None


def non_finite_key(obj: Any) -> str | None:
    """Dotted key path of the first NaN/Infinity in a parsed JSON document, or None
    (iterative: depth is bounded by the parser already)."""
    stack: list[tuple[str, Any]] = [("", obj)]
    while stack:
        key, v = stack.pop()
        if isinstance(v, float) and not math.isfinite(v):
            return key or "<root>"
        if isinstance(v, dict):
            stack.extend((f"{key}.{k}" if key else str(k), x) for k, x in reversed(list(v.items())))
        elif isinstance(v, list):
            stack.extend((f"{key}.{i}" if key else str(i), x) for i, x in reversed(list(enumerate(v))))
    return None


def load_schema(name: str) -> dict:
    """A bundled JSON Schema by file name, e.g. ``load_schema('manifest.schema.json')``."""
    from importlib import resources

    return json.loads(resources.files("datasets_spec").joinpath(name).read_text(encoding="utf-8"))


# -- frames ------------------------------------------------------------------
def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _mat4_problem(v: Any) -> str | None:
    if not (
        isinstance(v, list)
        and len(v) == 4
        and all(isinstance(r, list) and len(r) == 4 and all(_is_number(x) for x in r) for r in v)
    ):
        return "must be a 4x4 list of finite numbers"
    return None


def _path_problem(v: Any, suffix: tuple[str, ...]) -> str | None:
    if not isinstance(v, str) or not v or not RELPATH.match(v) or not v.endswith(suffix):
        ends = " or ".join(suffix)
        return f"{v!r} {RELPATH_RULE.replace('(allowed: ', f'(allowed: a name ending in {ends}, ')}"
    return None


def _markers_problem(v: Any) -> tuple[str, str] | None:
    if not isinstance(v, dict):
        return "markers", "must be an object"
    for mid, m in v.items():
        where = f"markers.{mid}"
        if not mid or not isinstance(m, dict) or set(m) != {"in_fov", "visible_fraction", "T_cam_marker"}:
            return where, "must be {in_fov, visible_fraction, T_cam_marker}"
        if not isinstance(m["in_fov"], bool):
            return f"{where}.in_fov", "must be true or false"
        if not (_is_number(m["visible_fraction"]) and 0 <= m["visible_fraction"] <= 1):
            return f"{where}.visible_fraction", "must be a number in [0, 1]"
        if _mat4_problem(m["T_cam_marker"]):
            return f"{where}.T_cam_marker", "must be a 4x4 list of finite numbers"
    return None


FRAME_REQUIRED = ("index", "t", "t_pose", "image", "T_world_cam", "T_cam_dock", "d_true", "markers")
FRAME_OPTIONAL = ("depth", "object_index")


def frame_problem(frame: Any) -> tuple[str, str] | None:
    """``(key, what is wrong)`` of the first rule of frame.schema.json the record breaks, or None."""
    if not isinstance(frame, dict):
        return "<root>", "a frame must be a JSON object"
    for key in FRAME_REQUIRED:
        if key not in frame:
            return key, "required key missing"
    extra = set(frame) - set(FRAME_REQUIRED) - set(FRAME_OPTIONAL)
    if extra:
        return sorted(extra)[0], "unknown key (allowed: " + ", ".join(FRAME_REQUIRED + FRAME_OPTIONAL) + ")"
    idx = frame["index"]
    if not isinstance(idx, int) or isinstance(idx, bool) or not 0 <= idx <= MAX_FRAME_INDEX:
        return "index", f"must be an integer in [0, {MAX_FRAME_INDEX}]"
    for key in ("t", "t_pose"):
        if not _is_number(frame[key]):
            return key, "must be a finite number (s)"
    if not (_is_number(frame["d_true"]) and frame["d_true"] >= 0):
        return "d_true", "must be a finite number >= 0 (m)"
    # depth: 1.1 writes uint16 millimetre PNGs, 1.0 wrote float32 NPZ (both readable)
    for key, suffix in (("image", (".png",)), ("depth", (".png", ".npz")), ("object_index", (".png",))):
        if key in frame and (problem := _path_problem(frame[key], suffix)):
            return key, problem
    for key in ("T_world_cam", "T_cam_dock"):
        if problem := _mat4_problem(frame[key]):
            return key, problem
    return _markers_problem(frame["markers"])


_FRAME_VALIDATOR = None


def schema_message(frame: Any) -> str | None:
    """jsonschema's own best message for a frame record (key path: message), or None if valid."""
    global _FRAME_VALIDATOR
    import jsonschema

    if _FRAME_VALIDATOR is None:
        _FRAME_VALIDATOR = jsonschema.Draft202012Validator(load_schema("frame.schema.json"))
    err = jsonschema.exceptions.best_match(_FRAME_VALIDATOR.iter_errors(frame))
    if err is None:
        return None
    key = ".".join(str(p) for p in err.absolute_path) or "<root>"
    msg = err.message if len(err.message) < 160 else err.message[:150] + "..."
    return f"{key}: {msg}"


def check_frame_record(frame: Any) -> None:
    """Raise ContentError ``"key: problem (allowed ...)"`` if the record breaks frame.schema.json."""
    problem = frame_problem(frame)
    if problem is not None:
        key, what = problem
        raise ContentError(f"{key}: {what}")


# -- camera ------------------------------------------------------------------
def camera_problem(camera: dict) -> str | None:
    """A manifest camera that cannot describe real images: size out of range, K not a
    finite upper-triangular intrinsic matrix with positive focal lengths."""
    for key in ("width", "height"):
        v = camera.get(key)
        if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= MAX_IMAGE_SIDE:
            return f"camera.{key}: {v!r} out of range (allowed: integer 1..{MAX_IMAGE_SIDE} px)"
    K = camera.get("K")
    if not (
        isinstance(K, list)
        and len(K) == 3
        and all(isinstance(r, list) and len(r) == 3 for r in K)
        and all(_is_number(x) for r in K for x in r)
    ):
        return "camera.K: must be a 3x3 matrix of finite numbers"
    if not (K[0][0] > 0 and K[1][1] > 0 and K[1][0] == K[2][0] == K[2][1] == 0 and K[2][2] == 1):
        return f"camera.K: {K} is not an intrinsic matrix (allowed: fx, fy > 0, last row [0, 0, 1])"
    dist = camera.get("distortion")
    if dist is not None and not (isinstance(dist, list) and all(_is_number(x) for x in dist)):
        return "camera.distortion: must be null or 5 finite numbers"
    return None


# -- PNG header --------------------------------------------------------------
PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def png_header(path: Path) -> tuple[int, int, int, int]:
    """``(width, height, bit_depth, color_type)`` from the 33-byte PNG start (signature +
    IHDR chunk with its CRC), read without decoding a pixel; the file must also end with
    the 12-byte IEND chunk (a truncated PNG does not). ContentError if it is not one."""
    with open(path, "rb") as fh:
        head = fh.read(33)
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(max(size - 12, 0))
        tail = fh.read(12)
    if len(head) < 33 or not head.startswith(PNG_SIGNATURE):
        raise ContentError("not a PNG file (bad signature or shorter than its header)")
    length, kind = struct.unpack(">I4s", head[8:16])
    data, crc = head[16:29], struct.unpack(">I", head[29:33])[0]
    if kind != b"IHDR" or length != 13 or zlib.crc32(kind + data) != crc:
        raise ContentError("not a PNG file (first chunk is not a valid IHDR)")
    if tail != PNG_IEND:
        raise ContentError("truncated PNG (no IEND chunk at its end)")
    width, height, depth, color, _, _, _ = struct.unpack(">IIBBBBB", data)
    return width, height, depth, color


def image_problem(header: tuple[int, int, int, int], width: int, height: int) -> str | None:
    """How a PNG header differs from the manifest camera's 8-bit RGB ``width`` x ``height``."""
    w, h, depth, color = header
    if (w, h) != (width, height):
        return f"image is {w}x{h} px; the manifest camera is {width}x{height}"
    if depth != 8 or color != 2:
        return (
            f"image is {depth}-bit {PNG_COLOR_TYPES.get(color, f'color type {color}')} "
            f"with {({0: 1, 2: 3, 3: 1, 4: 2, 6: 4}).get(color, '?')} channel(s); "
            "allowed: 8-bit RGB (3 channels, FORMAT.md)"
        )
    return None
