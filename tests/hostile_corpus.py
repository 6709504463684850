"""A corpus of hostile inputs for dockbench: bad configs, crafted datasets
and misbehaving localizers, each with the CLI arguments that feed it to dockbench.

``python tests/hostile_corpus.py [--before]`` runs every case and prints the table
``case | rc | message``; tests/test_hostile.py runs the same cases under pytest and
asserts the outcome after the fix (rc 2, the expected text, nothing written).

A case's ``build(base) -> argv`` writes its inputs under ``base`` (a fresh folder) and
returns the ``dockbench`` arguments; output folders are always ``base/a/b/out`` so a
write that escapes ``-o`` shows up as a new file elsewhere under ``base``.
Dataset cases tamper with a tiny valid dataset (tests/fake_dataset.py) and then
re-hash the manifest, as an attacker would, so sha256 checks cannot be what refuses them.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import struct
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.fake_dataset import write_fake_dataset  # noqa: E402

SEQ = "sequences/clear_000"
GOOD_CONFIG = {
    "name": "hostile",
    "seed": 1,
    "camera": {"width": 32, "height": 24},
    "render": {"samples": 1},
    "scene": {"dock": {"markers": [{"kind": "aruco", "id": "a", "size_m": 0.3}]}},
    "trajectories": [{"kind": "linear", "id": "lin", "start_range_m": 1.5, "end_range_m": 1.0}],
}


@dataclass
class Case:
    """One hostile input: ``build(base) -> argv``; after the fix dockbench must exit
    with ``rc`` and print ``expect`` (and, for rc 2, write nothing)."""

    name: str
    kind: str  # "config" | "dataset" | "verify" | "localizer"
    build: Callable[[Path], list[str]]
    expect: str
    rc: int = 2


def out_dir(base: Path) -> Path:
    return base / "a" / "b" / "out"


# ------------------------------------------------------------------ configs
def _cfg_text(base: Path, text: str | bytes) -> list[str]:
    p = base / "cfg.yaml"
    (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
    return ["generate", str(p), "-o", str(out_dir(base))]


def _cfg(edit: Callable[[dict], None] | None = None, out: str | None = None):
    def build(base: Path) -> list[str]:
        cfg = copy.deepcopy(GOOD_CONFIG)
        if edit:
            edit(cfg)
        argv = _cfg_text(base, yaml.safe_dump(cfg, allow_unicode=True))
        if out is not None:
            argv[-1] = out.format(base=base, root=ROOT)
            if "{base}/link" in out:
                (base / "link").symlink_to(ROOT / "evalkit", target_is_directory=True)
        return argv

    return build


def _set(path: str, value):
    def edit(cfg: dict) -> None:
        node = cfg
        keys = path.split(".")
        for k in keys[:-1]:
            node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
        node[int(keys[-1]) if isinstance(node, list) else keys[-1]] = value

    return edit


def _good_yaml() -> str:
    return yaml.safe_dump(GOOD_CONFIG)


def _nested_yaml(depth: int) -> str:
    return _good_yaml() + "water:\n  extra: " + "[" * depth + "]" * depth + "\n"


def _alias_bomb() -> str:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 9):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    return _good_yaml() + "\n".join(lines) + "\n"


def _huge_yaml() -> str:
    return _good_yaml() + "# " + "x" * (3 << 20) + "\n"


def _duplicate_key() -> str:
    return "seed: 7\n" + _good_yaml().replace("seed: 1\n", "") + "seed: 8\n"


def _template_case(base: Path) -> list[str]:
    (base / "tpl.yaml").write_bytes(b"pool: {length_m: 10}\n# \xff\n")
    cfg = copy.deepcopy(GOOD_CONFIG)
    cfg["scene"]["template"] = "tpl.yaml"
    return _cfg_text(base, yaml.safe_dump(cfg))


CONFIG_CASES = [
    Case("cfg_non_utf8", "config", lambda b: _cfg_text(b, _good_yaml().encode() + b"# caf\xe9 \xff\xfe\n"), "UTF-8"),
    Case("cfg_yaml_nested_5000", "config", lambda b: _cfg_text(b, _nested_yaml(5000)), "nested"),
    Case("cfg_yaml_alias_bomb", "config", lambda b: _cfg_text(b, _alias_bomb()), "alias"),
    Case("cfg_yaml_3MiB", "config", lambda b: _cfg_text(b, _huge_yaml()), "MiB"),
    Case("cfg_duplicate_key", "config", lambda b: _cfg_text(b, _duplicate_key()), "duplicate key 'seed'"),
    Case(
        "cfg_python_tag",
        "config",
        lambda b: _cfg_text(b, _good_yaml() + "x: !!python/object/apply:os.system ['true']\n"),
        "YAML",
    ),
    Case("cfg_out_in_proc", "config", _cfg(out="/proc/dockbench_hostile_out"), "/proc/dockbench_hostile_out"),
    Case("cfg_out_is_file", "config", _cfg(out="{base}/cfg.yaml"), "cfg.yaml"),
    Case("cfg_out_in_source_tree", "config", _cfg(out="{root}/evalkit/hostile_out"), "source"),
    Case("cfg_traj_id_dotdot", "config", _cfg(_set("trajectories.0.id", "../../../X")), "trajectories.0.id"),
    Case("cfg_marker_id_abs", "config", _cfg(_set("scene.dock.markers.0.id", "/../../../../X")), "markers.0.id"),
    Case("cfg_marker_id_slash", "config", _cfg(_set("scene.dock.markers.0.id", "a/b")), "markers.0.id"),
    Case("cfg_marker_id_nul", "config", _cfg(_set("scene.dock.markers.0.id", "a\x00b")), "markers.0.id"),
    Case("cfg_marker_id_backslash", "config", _cfg(_set("scene.dock.markers.0.id", "..\\..\\X")), "markers.0.id"),
    Case(
        "cfg_traj_id_confusable", "config", _cfg(_set("trajectories.0.id", "l\u0456n")), "trajectories.0.id"
    ),  # Cyrillic i
    Case("cfg_traj_id_empty", "config", _cfg(_set("trajectories.0.id", "")), "trajectories.0.id"),
    Case("cfg_traj_id_300_chars", "config", _cfg(_set("trajectories.0.id", "x" * 300)), "trajectories.0.id"),
    Case("cfg_condition_dotdot", "config", _cfg(_set("conditions", [{"label": ".."}])), "conditions.0.label"),
    Case("cfg_name_dotdot", "config", _cfg(_set("name", "..")), "name"),
    Case("cfg_name_dot_hidden", "config", _cfg(_set("name", ".hidden")), "name"),
    Case("cfg_out_symlink_into_source", "config", _cfg(out="{base}/link/x"), "source tree"),
    Case("cfg_template_not_utf8", "config", lambda b: _template_case(b), "UTF-8"),
    Case("cfg_trials_100000", "config", _cfg(_set("trials", 100000)), "trials"),
    Case("cfg_frames_1e12", "config", _cfg(_set("trajectories.0.speed_mps", 1e-9)), "frames"),
    Case(
        "cfg_fps_x_time_huge",
        "config",
        _cfg(
            lambda c: (
                c["camera"].update(fps=1000.0),
                c["trajectories"].__setitem__(0, {"kind": "docking", "id": "d", "max_time_s": 3600}),
            )
        ),
        "frames",
    ),
]


# ------------------------------------------------------------------ datasets
def rehash(root: Path) -> None:
    """Recompute every sha256 and the content hash, as an attacker who edits files would."""
    try:
        m = json.loads((root / "manifest.json").read_text())
    except (ValueError, RecursionError):  # the manifest itself is the attack
        return
    files = {}
    for rel in m.get("files", {}):
        p = root / rel
        if p.is_file():  # regular files only (through a symlink too); never /dev/zero
            files[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        else:
            files[rel] = m["files"][rel]
    m["files"] = files
    m["content_hash"] = hashlib.sha256("".join(f"{p} {files[p]}\n" for p in sorted(files)).encode()).hexdigest()
    (root / "manifest.json").write_text(json.dumps(m))


def _png(width: int, height: int, bit_depth: int = 8, color_type: int = 2, rows: int | None = None) -> bytes:
    """A valid PNG of zero pixels (filter 0 rows), built without decoding anything."""
    channels = {0: 1, 2: 3, 4: 2, 6: 4}[color_type]
    row = bytes(1 + width * channels * bit_depth // 8)
    comp = zlib.compressobj(9)
    body = b"".join(comp.compress(row) for _ in range(height if rows is None else rows)) + comp.flush()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, color_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", body) + chunk(b"IEND", b"")


_BOMB: dict[int, bytes] = {}


def png_bomb(side: int = 30000) -> bytes:
    """A valid side x side 8-bit RGB PNG of zeros (30000: 2.6 MB on disk, 2.7 GB decoded)."""
    if side not in _BOMB:
        cache = Path(os.environ.get("TMPDIR", "/tmp")) / f"dockbench-png-bomb-{side}.png"
        if not cache.is_file():
            tmp = cache.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_bytes(_png(side, side))
            os.replace(tmp, cache)
        _BOMB[side] = cache.read_bytes()
    return _BOMB[side]


def _lines(root: Path) -> list[str]:
    return (root / SEQ / "frames.jsonl").read_text().splitlines()


def _write_lines(root: Path, lines: list[str]) -> None:
    (root / SEQ / "frames.jsonl").write_text("\n".join(lines) + "\n")


def _frame_edit(i: int, edit: Callable[[dict], None]):
    def tamper(root: Path) -> None:
        lines = _lines(root)
        f = json.loads(lines[i])
        edit(f)
        lines[i] = json.dumps(f)
        _write_lines(root, lines)

    return tamper


def _manifest_edit(edit: Callable[[dict], None]):
    def tamper(root: Path) -> None:
        m = json.loads((root / "manifest.json").read_text())
        edit(m)
        (root / "manifest.json").write_text(json.dumps(m))

    return tamper


def _outside_png(root: Path) -> Path:
    """A good-looking 64x48 PNG outside the dataset (the attacker's file)."""
    p = root.parent / "outside" / "secret.png"
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(_png(64, 48))
    return p


def _image_bytes(data_fn: Callable[[], bytes], index: int = 1):
    def tamper(root: Path) -> None:
        (root / SEQ / "rgb" / f"{index:06d}.png").write_bytes(data_fn())

    return tamper


def _abs_image(root: Path) -> None:
    target = _outside_png(root)
    _frame_edit(1, lambda f: f.update(image=str(target)))(root)


def _symlink_image(root: Path) -> None:
    target = _outside_png(root)
    p = root / SEQ / "rgb" / "000001.png"
    p.unlink()
    p.symlink_to(target)


def _symlink_sequence(root: Path) -> None:
    import shutil

    outside = root.parent / "outside_seq"
    shutil.move(str(root / SEQ), outside)
    (root / SEQ).symlink_to(outside, target_is_directory=True)


def _frames_dev_zero(root: Path) -> None:
    (root / SEQ / "frames.jsonl").unlink()
    (root / SEQ / "frames.jsonl").symlink_to("/dev/zero")


def _manifest_symlink(root: Path) -> None:
    outside = root.parent / "outside_manifest.json"
    (root / "manifest.json").rename(outside)
    (root / "manifest.json").symlink_to(outside)


def _dotdot_image(path: str):
    def tamper(root: Path) -> None:
        _outside_png(root)
        _frame_edit(1, lambda f: f.update(image=path))(root)

    return tamper


def _manifest_deep(root: Path) -> None:
    text = (root / "manifest.json").read_text()
    (root / "manifest.json").write_text(text[:-1] + ', "deep": ' + "[" * 100000 + "]" * 100000 + "}")


def _frame_line_deep(root: Path) -> None:
    lines = _lines(root)
    lines[1] = lines[1][:-1] + ', "deep": ' + "[" * 100000 + "]" * 100000 + "}"
    _write_lines(root, lines)


def _huge_line(root: Path) -> None:
    lines = _lines(root)
    lines[1] = lines[1][:-1] + ', "pad": "' + "x" * (8 << 20) + '"}'
    _write_lines(root, lines)


def _nan_everywhere(root: Path) -> None:
    nan = float("nan")
    _frame_edit(
        1,
        lambda f: f.update(
            t=nan,
            t_pose=nan,
            T_world_cam=[[nan] * 4] * 4,
            markers={"0": {"in_fov": True, "visible_fraction": nan, "T_cam_marker": [[nan] * 4] * 4}},
        ),
    )(root)


def _jpeg_as_png(root: Path) -> None:
    import cv2
    import numpy as np

    ok, buf = cv2.imencode(".jpg", np.zeros((48, 64, 3), np.uint8))
    (root / SEQ / "rgb" / "000001.png").write_bytes(buf.tobytes())


def _ds(tamper: Callable[[Path], None], command: str = "evaluate"):
    def build(base: Path) -> list[str]:
        root = write_fake_dataset(base / "ds")
        tamper(root)
        rehash(root)
        if command == "verify":
            return ["verify", str(root)]
        return ["evaluate", str(root), "-l", "aruco", "-o", str(out_dir(base))]

    return build


def _frames_fifo(root: Path) -> None:
    (root / SEQ / "frames.jsonl").unlink()
    os.mkfifo(root / SEQ / "frames.jsonl")


def _image_is_dir(root: Path) -> None:
    p = root / SEQ / "rgb" / "000001.png"
    p.unlink()
    p.mkdir()


def _truncated_idat(root: Path) -> None:
    data = _png(64, 48)
    (root / SEQ / "rgb" / "000001.png").write_bytes(data[:60])


_DATASET_TAMPERS = [
    ("png_bomb_30000", _image_bytes(png_bomb), "30000x30000"),
    ("image_wrong_size", _image_bytes(lambda: _png(32, 24)), "32x24"),
    ("image_rgba16", _image_bytes(lambda: _png(64, 48, 16, 6)), "16-bit"),
    ("image_gray", _image_bytes(lambda: _png(64, 48, 8, 0)), "channel"),
    ("image_jpeg_named_png", _jpeg_as_png, "not a PNG"),
    ("image_truncated_header", _image_bytes(lambda: b"\x89PNG\r\n"), "not a PNG"),
    ("image_abs_path_outside", _abs_image, "image"),
    ("image_symlink_outside", _symlink_image, "outside the dataset"),
    ("image_dotdot_path", _dotdot_image("sequences/../../outside/secret.png"), "image"),
    ("image_zip_slip", _dotdot_image("sequences/clear_000/rgb/../../../../outside/secret.png"), "image"),
    ("image_backslash_path", _dotdot_image("..\\outside\\secret.png"), "image"),
    ("image_nul_byte", _frame_edit(1, lambda f: f.update(image="sequences/clear_000/rgb/0\x00.png")), "image"),
    (
        "image_confusable_name",
        _frame_edit(1, lambda f: f.update(image="sequences/clear_000/rgb/000001.p\u0578g")),
        "image",
    ),
    ("sequence_dir_symlink_outside", _symlink_sequence, "outside the dataset"),
    ("frames_symlink_dev_zero", _frames_dev_zero, "outside the dataset"),
    ("manifest_symlink_outside", _manifest_symlink, "outside the dataset"),
    ("T_cam_dock_ragged", _frame_edit(1, lambda f: f.update(T_cam_dock=[[1, 0, 0], [0, 1, 0, 0]])), "T_cam_dock"),
    ("T_cam_dock_string", _frame_edit(1, lambda f: f.update(T_cam_dock="eye(4)")), "T_cam_dock"),
    ("T_cam_dock_nan", _frame_edit(1, lambda f: f.update(T_cam_dock=[[float("nan")] * 4] * 4)), "T_cam_dock"),
    ("index_duplicate", _frame_edit(2, lambda f: f.update(index=1)), "index"),
    ("index_1e30", _frame_edit(1, lambda f: f.update(index=10**30)), "index"),
    ("index_negative", _frame_edit(1, lambda f: f.update(index=-1)), "index"),
    ("d_true_nan", _frame_edit(1, lambda f: f.update(d_true=float("nan"))), "d_true"),
    ("d_true_inf", _frame_edit(1, lambda f: f.update(d_true=float("inf"))), "d_true"),
    ("d_true_negative", _frame_edit(1, lambda f: f.update(d_true=-1.0)), "d_true"),
    ("nan_everywhere", _nan_everywhere, "frames.jsonl"),
    ("frame_line_8MiB", _huge_line, "MiB"),
    ("frame_line_nested_100000", _frame_line_deep, "nested"),
    ("manifest_nested_100000", _manifest_deep, "nested"),
    ("K_nan", _manifest_edit(lambda m: m["camera"]["K"][0].__setitem__(0, float("nan"))), "camera.K"),
    ("camera_size_1e9", _manifest_edit(lambda m: m["camera"].update(width=10**9)), "camera.width"),
    ("sequence_path_dotdot", _manifest_edit(lambda m: m["sequences"][0].update(path="sequences/../../x")), "path"),
    ("manifest_file_key_abs", _manifest_edit(lambda m: m["files"].update({"/etc/passwd": "0" * 64})), "files"),
    ("frames_fifo", _frames_fifo, "frames"),
    ("image_is_directory", _image_is_dir, "000001.png"),
    ("image_truncated_idat", _truncated_idat, "000001.png"),
    (
        "marker_keypoint_nan",
        _manifest_edit(lambda m: m["markers"][0]["keypoints"][0].__setitem__(0, float("nan"))),
        "markers.0.keypoints.0.0",
    ),
    ("d_min_rel_nan", _manifest_edit(lambda m: m.update(d_min_rel_m=float("nan"))), "d_min_rel_m"),
    ("n_frames_1e30", _manifest_edit(lambda m: m["sequences"][0].update(n_frames=10**30)), "n_frames"),
    (
        "sequence_path_confusable",
        _manifest_edit(lambda m: m["sequences"][0].update(path="sequences/clear_\u041e00")),
        "frames",
    ),  # Cyrillic O
    (
        "sequence_path_escapes_sequences",
        _manifest_edit(lambda m: m["sequences"][0].update(path="sequences")),
        "sequences.0.path",
    ),
]
DATASET_CASES = [Case(f"ds_{n}", "dataset", _ds(t), e) for n, t, e in _DATASET_TAMPERS]
VERIFY_CASES = [
    Case(f"verify_{n}", "verify", _ds(t, "verify"), e) for n, t, e in _DATASET_TAMPERS if n not in ("png_bomb_30000",)
] + [Case("verify_png_bomb_30000", "verify", _ds(_image_bytes(png_bomb), "verify"), "30000x30000")]


# ------------------------------------------------------------------ localizers
PLUGIN = """
import os, sys
class Bad:
    def __init__(self, how="systemexit"):
        self.how = how
    def reset(self, camera):
        pass
    def localize(self, image):
        how = self.how
        if how == "systemexit":
            raise SystemExit(0)
        if how == "keyboardinterrupt":
            raise KeyboardInterrupt
        if how == "os_exit":
            os._exit(3)
        if how == "huge":
            return {"distance": 1e308}
        if how == "string":
            return {"distance": "3.0"}
        if how == "bool":
            return {"distance": True}
        if how == "slow":
            import time
            time.sleep(0.3)
            return None
        if how == "memory":
            blob = bytearray(8 << 30)
            return {"distance": 1.0}
        return None
"""

LONG_LINE = """
import sys, json
for line in sys.stdin:
    req = json.loads(line)
    if req["type"] == "reset":
        print(json.dumps({"ok": True}), flush=True)
    else:
        chunk = "x" * (1 << 20)
        for _ in range(int(sys.argv[1])):
            sys.stdout.write(chunk)
        sys.stdout.flush()
"""


def _loc(how: str, extra: tuple[str, ...] = ()):
    def build(base: Path) -> list[str]:
        root = write_fake_dataset(base / "ds")
        plugin = base / "bad_plugin.py"
        plugin.write_text(PLUGIN)
        return ["evaluate", str(root), "-l", f"{plugin}:Bad", "-p", f"how={how}", "-o", str(out_dir(base)), *extra]

    return build


def _long_line(mib: int):
    def build(base: Path) -> list[str]:
        root = write_fake_dataset(base / "ds")
        prog = base / "long_line.py"
        prog.write_text(LONG_LINE)
        return [
            "evaluate",
            str(root),
            "-l",
            f"exec:{sys.executable} {prog} {mib}",
            "-o",
            str(out_dir(base)),
            "--frame-timeout",
            "20",
        ]

    return build


# rc 0 here: the run completes and the frames fail with the reason in ``expect`` (estimates)
LOCALIZER_CASES = [
    Case("loc_systemexit", "localizer", _loc("systemexit"), "exception: SystemExit", rc=0),
    Case(
        "loc_systemexit_in_process", "localizer", _loc("systemexit", ("--in-process",)), "exception: SystemExit", rc=0
    ),
    Case("loc_keyboardinterrupt_raised", "localizer", _loc("keyboardinterrupt"), "exception: KeyboardInterrupt", rc=0),
    Case(
        "loc_keyboardinterrupt_in_process",
        "localizer",
        _loc("keyboardinterrupt", ("--in-process",)),
        "exception: KeyboardInterrupt",
        rc=0,
    ),
    Case("loc_os_exit", "localizer", _loc("os_exit"), "crash: exit code 3", rc=0),
    Case("loc_distance_1e308", "localizer", _loc("huge", ("--in-process",)), "out_of_range", rc=0),
    Case("loc_distance_string", "localizer", _loc("string", ("--in-process",)), "bad_type", rc=0),
    Case("loc_distance_bool", "localizer", _loc("bool", ("--in-process",)), "bad_type", rc=0),
    Case("loc_isolated_8GiB", "localizer", _loc("memory", ("--isolate",)), "MemoryError", rc=0),
    Case("loc_exec_64MiB_line", "localizer", _long_line(64), "protocol: reply line longer than", rc=0),
]


# ------------------------------------------------------------------ run folders, outputs, exports, results
def _cfg_file(base: Path) -> Path:
    p = base / "cfg.yaml"
    p.write_text(_good_yaml())
    return p


def _run_into(prepare: Callable[[Path], Path]):
    """``dockbench run`` into the folder ``prepare(base)`` returns (stopped before rendering)."""

    def build(base: Path) -> list[str]:
        out = prepare(base)
        return ["run", str(_cfg_file(base)), "-l", "aruco", "-o", str(out)]

    return build


def _pickle_cache(base: Path) -> Path:
    """A run folder handed over 'to resume' whose cache is a pickle that runs code."""
    import pickle

    work = base / "run" / ".stream" / GOOD_CONFIG["name"]
    work.mkdir(parents=True)

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {base / 'PWNED'}",))

    (work / "lin-t000-clear.pkl.gz").write_bytes(pickle.dumps(Payload()))
    return base / "run"


def _generating(base: Path) -> Path:
    """A dataset folder `generate` is writing (its config stamp, no manifest yet)."""
    (base / "gen" / ".work").mkdir(parents=True)
    (base / "gen" / ".work" / "config.sha256").write_text("0" * 64 + "\n")
    return base / "gen"


def _foreign(base: Path) -> Path:
    (base / "mine").mkdir()
    (base / "mine" / "thesis.tex").write_text("\\documentclass{article}\n")
    return base / "mine"


def _export(tamper: Callable[[Path], None] | None = None, out: str = "{base}/a/b/out", extra=()):
    def build(base: Path) -> list[str]:
        root = write_fake_dataset(base / "ds")
        if tamper:
            tamper(root)
            rehash(root)
        if "{base}/mine" in out:
            _foreign(base)
        return ["export-bop", str(root), "-o", out.format(base=base), *extra]

    return build


def _unlisted_image(root: Path) -> None:
    m = json.loads((root / "manifest.json").read_text())
    del m["files"][f"{SEQ}/rgb/000001.png"]
    (root / "manifest.json").write_text(json.dumps(m))


def _no_sequences(root: Path) -> None:
    _manifest_edit(lambda m: m.update(sequences=[]))(root)


def _stream_json(text_fn: Callable[[Path], str]):
    def build(base: Path) -> list[str]:
        root = write_fake_dataset(base / "ds")
        p = base / "stream.json"
        p.write_text(text_fn(root))
        return ["verify", str(root), "--stream", str(p)]

    return build


def _good_stream(root: Path, **edit) -> str:
    from datasets_spec.io import dataset_files

    files = {rel: hashlib.sha256((root / rel).read_bytes()).hexdigest() for rel in dataset_files(root)}
    return json.dumps({"format": "dockbench-stream", "format_version": "2", "files": files, "pixels": {}, **edit})


def _calibrate(text: str):
    def build(base: Path) -> list[str]:
        (base / "calib.json").write_text(text)
        return ["calibrate-veil", "--data", str(base / "calib.json"), "-o", str(out_dir(base))]

    return build


def _results(edit: Callable[[Path], None]):
    """A results folder of `evaluate` on the tiny dataset, hand-edited, fed to `leaderboard`."""

    def build(base: Path) -> list[str]:
        import shutil

        src = _evaluated_results()
        shutil.copytree(src, base / "res")
        edit(base / "res")
        return ["leaderboard", str(base / "res"), "-o", str(out_dir(base) / "lb.html")]

    return build


_RESULTS: list[Path] = []


def _evaluated_copy(base: Path) -> Path:
    import shutil

    shutil.copytree(_evaluated_results(), base / "res")
    return base / "res"


def _evaluated_results() -> Path:
    """One `dockbench evaluate` of the tiny dataset per process (its results are copied)."""
    if not _RESULTS:
        import tempfile

        from click.testing import CliRunner

        import cli

        tmp = Path(tempfile.mkdtemp(prefix="dockbench-hostile-results-"))
        root = write_fake_dataset(tmp / "ds")
        res = CliRunner().invoke(cli.main, ["evaluate", str(root), "-l", "aruco", "-o", str(tmp / "res"), "-q"])
        assert res.exit_code == 0, res.output
        _RESULTS.append(tmp / "res")
    return _RESULTS[0]


def _metric(col: str, value):
    def edit(res: Path) -> None:
        lines = (res / "metrics.csv").read_text().splitlines()
        head = lines[0].split(",")
        row = lines[1].split(",")
        row[head.index(col)] = str(value)
        (res / "metrics.csv").write_text("\n".join([lines[0], ",".join(row), *lines[2:]]) + "\n")

    return edit


def _closed_loop(value: float):
    def edit(res: Path) -> None:
        doc = {
            "format": "dockbench-closed-loop",
            "format_version": "1",
            "experiment": {"name": "x", "version": "1", "config_hash": "h"},
            "camera": {"latency_s": 0},
            "capture": {},
            "rows": [
                {
                    "localizer": "led",
                    "condition": "clear",
                    "n_trials": 2,
                    "n_docked": 1,
                    "success_rate": 0.5,
                    "ci_low": 0.1,
                    "ci_high": 0.9,
                    "final_lateral_abs_mean_m": value,
                }
            ],
        }
        for f in list(res.iterdir()):
            (f.unlink() if f.is_file() else None)
        (res / "closed_loop.json").write_text(json.dumps(doc))

    return edit


SURFACE_CASES = [
    # run folders: nothing a user hands over is deserialised as code
    Case("run_pickled_cache", "run", _run_into(_pickle_cache), "pickled cache"),
    Case("run_out_is_dataset", "run", _run_into(lambda b: write_fake_dataset(b / "ds")), "is the dataset"),
    Case(
        "run_out_inside_dataset",
        "run",
        _run_into(lambda b: write_fake_dataset(b / "ds") / "sequences"),
        "inside the dataset",
    ),
    Case("run_out_being_generated", "run", _run_into(_generating), "is the dataset"),
    Case("run_out_foreign_files", "run", _run_into(_foreign), "files dockbench did not write"),
    Case(
        "gen_out_inside_dataset",
        "config",
        lambda b: ["generate", str(_cfg_file(b)), "-o", str(write_fake_dataset(b / "ds") / "x")],
        "inside the dataset",
    ),
    Case(
        "eval_out_is_dataset_overwrite",
        "dataset",
        lambda b: ["evaluate", str(write_fake_dataset(b / "ds")), "-l", "aruco", "-o", str(b / "ds"), "--overwrite"],
        "is the dataset",
    ),
    Case("eval_no_sequences", "dataset", _ds(_no_sequences), '"sequences" is empty'),
    Case(
        "bench_out_foreign_files",
        "outdir",
        lambda b: ["bench", "pnp", "--trials", "5", "-o", str(_foreign(b))],
        "files dockbench did not write",
    ),
    Case(
        "bench_out_inside_dataset",
        "outdir",
        lambda b: ["bench", "pnp", "--trials", "5", "-o", str(write_fake_dataset(b / "ds") / "bench")],
        "inside the dataset",
    ),
    Case(
        "dock_out_inside_dataset",
        "outdir",
        lambda b: ["dock", "turbidity", "--report-only", "-o", str(write_fake_dataset(b / "ds") / "dock")],
        "inside the dataset",
    ),
    Case(
        "lb_page_into_dataset",
        "outdir",
        lambda b: ["leaderboard", str(_evaluated_copy(b)), "-o", str(write_fake_dataset(b / "ds") / "lb.html")],
        "inside the dataset",
    ),
    # export-bop: the same rule and the same checks as evaluate, before writing
    Case("bop_out_is_dataset", "export", _export(out="{base}/ds"), "is the dataset"),
    Case("bop_out_inside_dataset", "export", _export(out="{base}/ds/sequences/x"), "inside the dataset"),
    Case("bop_out_proc", "export", _export(out="/proc/dockbench_hostile_bop"), "pseudo file system"),
    Case("bop_out_foreign_files", "export", _export(out="{base}/mine"), "files dockbench did not write"),
    Case("bop_png_bomb_30000", "export", _export(_image_bytes(png_bomb)), "30000x30000"),
    Case("bop_image_not_in_manifest", "export", _export(_unlisted_image), "000001.png"),
    Case("bop_no_sequences", "export", _export(_no_sequences), '"sequences" is empty'),
    # verify --stream: a stream.json is untrusted input
    Case("stream_not_json", "stream", _stream_json(lambda r: "hello"), "not a stream.json"),
    Case("stream_truncated", "stream", _stream_json(lambda r: _good_stream(r)[:100]), "not a stream.json"),
    Case("stream_empty_list", "stream", _stream_json(lambda r: "[]"), "expected a JSON object"),
    Case("stream_nested_100000", "stream", _stream_json(lambda r: "[" * 100000 + "]" * 100000), "nested"),
    Case(
        "stream_path_etc_passwd",
        "stream",
        _stream_json(lambda r: _good_stream(r, files={"/etc/passwd": "0" * 64})),
        "relative path",
    ),
    Case(
        "stream_path_dotdot",
        "stream",
        _stream_json(lambda r: _good_stream(r, files={"../outside.png": "0" * 64})),
        "relative path",
    ),
    Case(
        "stream_format_version_99",
        "stream",
        _stream_json(lambda r: _good_stream(r, format_version=99)),
        "format_version 99",
    ),
    # calibration files are checked before any render
    Case("calib_data_not_json", "calibrate", _calibrate("not json at all"), "not JSON"),
    Case("calib_data_unknown_keys", "calibrate", _calibrate('{"secrets": 1}'), "unknown key 'secrets'"),
    # results are numbers anyone can edit
    Case("lb_P_succ_minus_500pct", "results", _results(_metric("P_succ_mean", -5.0)), "outside [0, 1]"),
    Case("lb_E_rel_1e308", "results", _results(_metric("E_rel_mean", 1e308)), "E_rel_mean"),
    Case("lb_E_rel_minus_1e308", "results", _results(_metric("E_rel_mean", -1e308)), "E_rel_mean"),
    Case("lb_counts_disagree", "results", _results(_metric("n_fp", 999)), "exceeds n_est"),
    Case("lb_closed_loop_lateral_1e308", "results", _results(_closed_loop(1e308)), "final_lateral_abs_mean_m"),
]

SANDBOX_PLUGIN = """
import os, sys
class Hostile:
    def __init__(self, how="write", target=""):
        self.how, self.target = how, target
    def reset(self, camera):
        pass
    def localize(self, image):
        if self.how == "write":
            open(self.target, "wb").write(b"overwritten by a plugin")
            return {"distance": 1.0}
        for _ in range(3):                         # detached children that hold every pipe
            if os.fork() == 0:
                os.setsid()
                if os.fork() == 0:
                    import time
                    time.sleep(600)
                os._exit(0)
        return None
"""


def _sandboxed(how: str):
    def build(base: Path) -> list[str]:
        root = write_fake_dataset(base / "ds")
        plugin = base / "hostile_plugin.py"
        plugin.write_text(SANDBOX_PLUGIN)
        target = root / SEQ / "rgb" / "000003.png"
        return [
            "evaluate",
            str(root),
            "-l",
            f"{plugin}:Hostile",
            "-p",
            f"how={how}",
            "-p",
            f"target={target}",
            "-o",
            str(out_dir(base)),
            "--frame-timeout",
            "20",
        ]

    return build


# rc 0 with the frames failed (write) or answered "none" while the children lived (fork); needs bubblewrap
SANDBOX_CASES = [
    Case("loc_plugin_overwrites_dataset_image", "sandbox", _sandboxed("write"), "Read-only file system", rc=0),
    Case("loc_plugin_forks_setsid_children", "sandbox", _sandboxed("fork"), "none", rc=0),
]

IN_PROCESS_SURFACES = SURFACE_CASES
ALL_CASES = CONFIG_CASES + DATASET_CASES + VERIFY_CASES + SURFACE_CASES + LOCALIZER_CASES + SANDBOX_CASES


# ------------------------------------------------------------------ running
def files_under(base: Path) -> set[str]:
    """Every path under ``base`` (symlinks not followed)."""
    out = set()
    for d, dirs, files in os.walk(base):
        for n in dirs + files:
            out.add(os.path.relpath(os.path.join(d, n), base))
    return out


def run_subprocess(argv: list[str], timeout_s: float = 300.0, limit_as: int | None = None) -> tuple[int, str, int]:
    """Run ``dockbench ARGV`` in a child; (rc, output, peak RSS of the child in kB).
    ``limit_as`` (bytes) caps the child's address space (used for the *before* bomb run)."""
    import resource
    import subprocess

    code = (
        "import resource, sys; lim = int(sys.argv[1]);\n"
        "lim and resource.setrlimit(resource.RLIMIT_AS, (lim, lim)); sys.argv = ['dockbench'] + sys.argv[2:]\n"
        "import os\nif os.environ.get('DOCKBENCH_HOSTILE_NO_RENDER'):\n"
        "    import blendgen.pipeline.generate as g\n"
        "    def _stub(*a, **k): raise RuntimeError('CONFIG ACCEPTED: rendering reached (skipped by the corpus)')\n"
        "    g._render = _stub\n"
        "import cli; cli.main()"
    )
    code_root = os.environ.get("DOCKBENCH_CODE_ROOT", str(ROOT))  # e.g. an export of the code as found
    env = {**os.environ, "PYTHONPATH": code_root, "DOCKBENCH_HOSTILE_NO_RENDER": "1"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    p = subprocess.run(
        [sys.executable, "-c", code, str(limit_as or 0), *argv],
        capture_output=True,
        text=True,
        errors="replace",
        timeout=timeout_s,
        env=env,
        cwd=code_root,
    )
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return p.returncode, p.stdout + p.stderr, peak if peak > before else -1


def summarize(rc: int, text: str) -> str:
    """The message a user sees: the first error line, or the last line of a traceback."""
    lines = [ln for ln in text.splitlines() if ln.strip()]
    for i, ln in enumerate(lines):
        if ln.startswith("error:"):
            if ln.endswith("problem(s):") and i + 1 < len(lines):  # verify: the first problem
                ln = f"{ln} {lines[i + 1].strip()}"
            return ln[:200]
    if any(ln.startswith("Traceback") for ln in lines):
        return ("TRACEBACK " + lines[-1])[:160]
    return (lines[-1] if lines else "")[:160]


def main(argv: list[str]) -> int:
    import tempfile
    import time

    names = [a for a in argv if not a.startswith("-")]
    rows = []
    for case in ALL_CASES:
        if names and not any(n in case.name for n in names):
            continue
        with tempfile.TemporaryDirectory(prefix="dockbench-hostile-") as tmp:
            base = Path(tmp)
            args = case.build(base)
            before = files_under(base)
            t0 = time.perf_counter()
            # a safety net for this shared machine: 4 GiB of address space except for the
            # localizer cases (their own limits are under test)
            rc, text, peak = run_subprocess(args, limit_as=None if case.kind == "localizer" else 4 << 30)
            new = sorted(files_under(base) - before)
            msg = summarize(rc, text)
            est = out_dir(base) / "estimates.parquet"
            if case.kind == "localizer" and est.is_file():
                import pandas as pd

                msg = "fail_reason: " + ", ".join(sorted(set(pd.read_parquet(est)["fail_reason"])))[:150]
            rows.append((case.name, rc, f"{time.perf_counter() - t0:.1f}", peak // 1024, len(new), msg))
            print(f"| {case.name} | {rc} | {rows[-1][2]} s | {rows[-1][3]} MB | {len(new)} new | {msg} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
