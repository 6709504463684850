"""A single static HTML leaderboard from result directories (no server, no internet).

``dockbench leaderboard RESULTS_DIR... -o board.html``: runs are grouped by the
dataset content they were computed on (``content_hash``) *and* their success
thresholds (runs on different data or judged by different thresholds are never
ranked together). Per dataset the page shows a localizer x (trajectory / condition)
matrix of ``P_succ``, then per (trajectory, condition) a ranked table and the
``P_succ`` per range bin. Ranking: ``P_succ_mean`` (thresholded success) descending,
ties by the rate of wrong answers ``P_detect - P_succ`` ascending (a wrong answer is
worse than none: the controller acts on it), then ``E_rel_mean`` ascending; NaN last.
Rendered by jinja2 (autoescape on) from ``templates/leaderboard.html.j2``; inline CSS
and a little inline JS (click a header to sort; ``#sort=<column>&dir=asc|desc`` sorts
every table on load). Laid out to fit a 1280 px wide window.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd

    from evalkit.reports.results import Run

# pandas and evalkit.reports.results are imported inside the functions so that wiring
# ``leaderboard_cmd`` into the CLI keeps ``dockbench --help`` fast.

# (key, header, kind, help): kind "pct_ci"/"pct" = fraction shown in %, "num", "int", "text"
COLUMNS: list[tuple[str, str, str, str]] = [
    ("rank", "#", "int", "rank in this trajectory / condition"),
    ("label", "localizer", "text", "localizer (hover: full spec and run)"),
    ("P_succ_mean", "P_succ %", "pct_ci", "frames localized within the success thresholds"),
    ("P_detect_mean", "P_detect %", "pct", "frames with any answer (the article's success rate)"),
    ("E_rel_mean", "E_rel %", "pct_ci", "mean relative distance error over answered frames"),
    (
        "AR_dock",
        "AR_dock",
        "num",
        "dockbench's dock-as-one-object recall: mean of MSSD and MSPD recalls (no VSD; "
        "not the BOP19 AR, see export-bop --results)",
    ),
    ("e_rot_deg_mean", "rot deg", "num", "mean rotation error (deg)"),
    ("n_fp", "FP", "int", "false positives: answers with no marker in view or a wrong id"),
    ("max_range_m", "range m", "num", "usable range: farthest 1 m bin with P_succ >= 90%"),
    ("ms_median", "ms", "num", "median ms per frame"),
    ("n_trials", "M", "int", "independent trials"),
]
CI_PREFIX = {"P_succ_mean": "P_succ", "E_rel_mean": "E_rel", "success_rate": "success"}
TEMPLATE = "leaderboard.html.j2"

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:16px;color:#1b1f24;
background:#fff;max-width:1240px}
h1{font-size:21px;margin:0 0 4px}h2{font-size:17px;margin:22px 0 4px;border-bottom:2px solid #d0d7de;padding-bottom:3px}
h3{font-size:14px;margin:14px 0 4px}.meta{color:#57606a;font-size:12px;margin:2px 0}
.warn{color:#9a6700;font-size:12px}b.warn{color:#cf222e}
table{border-collapse:collapse;font-size:12px;margin:4px 0}
th,td{border:1px solid #d0d7de;padding:2px 6px;white-space:nowrap}
th{background:#f6f8fa}table.lb th{cursor:pointer;user-select:none}
table.lb th.sorted-asc::after{content:" \\25B2"}table.lb th.sorted-desc::after{content:" \\25BC"}
td.n{text-align:right;font-variant-numeric:tabular-nums}td.lbl{max-width:190px;overflow:hidden;text-overflow:ellipsis}
table.lb tr.first td{background:#eaf5ea}table.lb tr.baseline td{background:#f3f0ff;font-style:italic}
td.bar-cell{position:relative}
.bar{position:absolute;left:0;bottom:0;height:3px;background:#2da44e}
.ci{color:#6e7781;font-size:10px}code{font-size:11px}
dl.legend{font-size:11px;color:#57606a;margin:4px 0;display:grid;grid-template-columns:max-content auto;gap:0 8px}
dl.legend dt{font-weight:600}dl.legend dd{margin:0}
"""

JS = """
(function(){
  function val(td){var v=td.getAttribute('data-v');if(v===null||v==='')return null;
    var f=parseFloat(v);return isNaN(f)?v.toLowerCase():f;}
  function sortTable(table,col,dir){
    var body=table.tBodies[0],rows=Array.prototype.slice.call(body.rows);
    var idx=-1,ths=table.tHead.rows[0].cells;
    for(var i=0;i<ths.length;i++){ths[i].classList.remove('sorted-asc','sorted-desc');
      if(ths[i].getAttribute('data-col')===col)idx=i;}
    if(idx<0)return;
    rows.sort(function(a,b){var x=val(a.cells[idx]),y=val(b.cells[idx]);
      if(x===null&&y===null)return 0;if(x===null)return 1;if(y===null)return -1;
      var c=(x<y)?-1:(x>y)?1:0;return dir==='asc'?c:-c;});
    rows.forEach(function(r){body.appendChild(r);});
    ths[idx].classList.add(dir==='asc'?'sorted-asc':'sorted-desc');
    table.setAttribute('data-sorted',col+':'+dir);
  }
  var tables=document.querySelectorAll('table.lb');
  tables.forEach(function(t){
    Array.prototype.forEach.call(t.tHead.rows[0].cells,function(th){
      th.addEventListener('click',function(){
        var col=th.getAttribute('data-col');
        var dir=th.classList.contains('sorted-desc')?'asc':(th.classList.contains('sorted-asc')?'desc':
                (th.getAttribute('data-kind')==='text'?'asc':'desc'));
        sortTable(t,col,dir);});});});
  var m=/sort=([^&]+)(?:&dir=(asc|desc))?/.exec(location.hash||'');
  if(m){tables.forEach(function(t){sortTable(t,decodeURIComponent(m[1]),m[2]||'desc');});}
  document.body.setAttribute('data-sortable','yes');
})();
"""


def _finite(v) -> bool:
    try:
        return v is not None and math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def short_name(spec: str, limit: int = 24) -> str:
    """A short display name for a ``-l`` spec: ``file.py:Class`` for a path target,
    ``exec:prog`` for an external program, else the spec (cut to ``limit`` characters)."""
    if spec.startswith("exec:"):
        words = spec[5:].split()
        prog = Path(words[0]).name if words else ""
        script = next((Path(w).name for w in words[1:] if "/" in w or "." in w), "")
        text = f"exec:{prog}" + (f" {script}" if script else "")
    elif ":" in spec and ("/" in spec.rpartition(":")[0] or spec.rpartition(":")[0].endswith(".py")):
        file_part, _, attr = spec.rpartition(":")
        text = f"{Path(file_part).name}:{attr}"
    else:
        text = spec
    return text if len(text) <= limit else text[: limit - 1] + "\u2026"


def _pct_text(v) -> str:
    return f"{100 * float(v):.1f}" if _finite(v) else "-"


def _ci_text(row, key: str) -> str | None:
    """``[lo, hi]`` in % with the mean's digits (rounding is monotonic: the printed mean stays inside)."""
    p = CI_PREFIX.get(key)
    if p is None or not (_finite(row.get(f"{p}_lo")) and _finite(row.get(f"{p}_hi"))):
        return None
    return f"[{100 * float(row[f'{p}_lo']):.1f}, {100 * float(row[f'{p}_hi']):.1f}]"


def _cell(row, key: str, kind: str) -> dict:
    """One table cell: text, sort value, CI, bar width (% for P_succ)."""
    v = row.get(key)
    out: dict[str, Any] = {"cls": "n", "v": "", "text": "-", "ci": None, "bar": None, "title": None}
    if kind == "text":
        return {**out, "cls": "lbl", "v": str(v), "text": str(v), "title": row.get("full")}
    if not _finite(v):
        return out
    f = float(v)
    out["v"] = f"{f:.9g}"
    if kind == "int":
        out["text"] = f"{int(f)}" + ("*" if key == "n_trials" and bool(row.get("few_trials")) else "")
        if key == "n_fp" and _finite(row.get("n_est")):
            out["title"] = f"{int(f)} of {int(row['n_est'])} answers"
    elif kind == "num":
        out["text"] = f"{f:.3g}"
    else:
        out["text"], out["ci"] = _pct_text(f), _ci_text(row, key)
        if key == "P_succ_mean":
            out["cls"], out["bar"] = "n bar-cell", round(100 * min(max(f, 0.0), 1.0), 1)
    return out


def rank(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of one (dataset, trajectory, condition) in rank order with a ``rank`` column (1 = best):
    ``P_succ_mean`` desc, wrong-answer rate ``P_detect_mean - P_succ_mean`` asc, ``E_rel_mean`` asc,
    label; NaN metrics last."""
    p = df["P_succ_mean"].astype(float)
    wrong = (df["P_detect_mean"].astype(float) - p).fillna(math.inf)
    out = df.assign(_p=-p.fillna(-math.inf), _w=wrong, _e=df["E_rel_mean"].astype(float).fillna(math.inf))
    out = out.sort_values(["_p", "_w", "_e", "label"], kind="stable").drop(columns=["_p", "_w", "_e"])
    out = out.reset_index(drop=True)
    out.insert(0, "rank", range(1, len(out) + 1))
    return out


def _shade(p) -> str:
    """Background for a P_succ cell: white (0) to green (1)."""
    if not _finite(p):
        return "#fff"
    a = min(max(float(p), 0.0), 1.0)
    return f"rgba(45,164,78,{0.08 + 0.5 * a:.2f})"


def _matrix(table: pd.DataFrame) -> dict:
    """Localizer x (trajectory / condition) of P_succ, rows by their worst cell (lowest P_succ, then
    label): trajectories are never averaged."""
    table = table.assign(_col=table["trajectory"].astype(str) + " / " + table["condition"].astype(str))
    cols = sorted(table["_col"].unique())
    rows = []
    for label, g in table.groupby("label", sort=True):
        by = g.set_index("_col")
        cells = []
        for c in cols:
            r = by.loc[c] if c in by.index else None
            p = None if r is None else r["P_succ_mean"]
            star = "*" if r is not None and bool(r.get("few_trials")) else ""
            cells.append({"text": _pct_text(p) + star if r is not None else "", "shade": _shade(p)})
        worst = g["P_succ_mean"].astype(float).min()  # never a mean: trajectories are not averaged
        rows.append({"label": label, "full": g["full"].iloc[0], "cells": cells, "_m": worst, "worst": _pct_text(worst)})
    rows.sort(key=lambda r: (-(r["_m"] if _finite(r["_m"]) else -1.0), r["label"]))
    for i, r in enumerate(rows, start=1):
        r["rank"] = i
    return {"columns": cols, "rows": rows}


def _bins(bins: pd.DataFrame | None) -> dict | None:
    """P_succ per range bin of one group: rows per label, columns per bin."""
    if bins is None or bins.empty:
        return None
    used = bins[bins["n_total"] > 0]  # bins no frame of this group reaches are left out
    edges = sorted(set(zip(used["bin_lo"], used["bin_hi"])))
    if not edges:
        return None
    rows = []
    for label, g in bins.groupby("label", sort=True):
        by = {(lo, hi): r for lo, hi, r in zip(g["bin_lo"], g["bin_hi"], g.to_dict("records"))}
        cells = []
        for e in edges:
            r = by.get(e)
            n = int(r["n_total"]) if r is not None else 0
            p = r["P_succ"] if r is not None and n else None
            cells.append(
                {
                    "text": f"{100 * float(p):.0f}" if p is not None and _finite(p) else "",
                    "shade": _shade(p),
                    "title": f"{n} frames",
                    "n": n,
                }
            )
        rows.append({"label": label, "cells": cells})
    return {"edges": [f"{lo:g}-{hi:g}" for lo, hi in edges], "rows": rows}


def _criteria(run: Run) -> dict:
    """The success thresholds a run was scored with (``{}`` for runs that predate them)."""
    return (run.run.get("settings") or {}).get("success") or {}


def group_runs(runs: Sequence[Run]) -> list[list[Run]]:
    """Runs grouped by dataset ``content_hash`` and success thresholds (order of first appearance)."""
    from evalkit.reports.results import ResultsError

    groups: dict[tuple[str, str], list[Run]] = {}
    for r in runs:
        if not r.content_hash:
            raise ResultsError(f"{r.path}: run.json has no dataset content_hash")
        groups.setdefault((r.content_hash, json.dumps(_criteria(r), sort_keys=True)), []).append(r)
    return list(groups.values())


def _labelled_bins(group: Sequence[Run], table: pd.DataFrame) -> pd.DataFrame | None:
    """bins.csv of every run with the board's labels."""
    import pandas as pd

    names = dict(zip(zip(table["run"], table["localizer"]), table["label"]))
    parts = []
    for r, run_label in zip(group, dict.fromkeys(table["run"])):
        if r.bins is None or not len(r.bins):
            continue
        b = r.bins.assign(**{c: r.bins[c].fillna("").astype(str) for c in ("localizer", "trajectory", "condition")})
        parts.append(b.assign(label=[names.get((run_label, loc), loc) for loc in b["localizer"]]))
    return pd.concat(parts, ignore_index=True) if parts else None


def _section(group: Sequence[Run], index: int) -> dict:
    """View model of one dataset (and thresholds) for the template."""
    from evalkit.metrics.extra import MIN_TRIALS_FOR_CI
    from evalkit.reports.results import compare_runs

    table = compare_runs(group)
    table["full"] = table["localizer"] + " (" + table["run"] + ")"
    table["label"] = [
        short_name(loc) + (lbl[len(loc) :] if lbl.startswith(loc) else "")
        for loc, lbl in zip(table["localizer"], table["label"])
    ]
    bins = _labelled_bins(group, table)
    groups = []
    for gi, ((traj, cond), g) in enumerate(table.groupby(["trajectory", "condition"], sort=True)):
        ranked = rank(g)
        rows = [
            {"label": r["label"], "cells": [_cell({**r, "full": r["full"]}, k, kind) for k, _, kind, _ in COLUMNS]}
            for r in ranked.to_dict("records")
        ]
        gb = None if bins is None else bins[(bins["trajectory"] == traj) & (bins["condition"] == cond)]
        groups.append(
            {
                "title": f"trajectory {traj or '-'} / condition {cond or '-'}",
                "id": f"t{index}-{gi}",
                "rows": rows,
                "bins": _bins(gb),
            }
        )
    crit = _criteria(group[0])
    ds = group[0].dataset
    return {
        "name": ds.get("name"),
        "version": ds.get("version"),
        "content_hash": group[0].content_hash,
        "criteria": {
            "max_rel_dist_pct": f"{100 * crit.get('max_rel_dist', math.nan):g}",
            "max_rel_trans_pct": f"{100 * crit.get('max_rel_trans', math.nan):g}",
            "min_tol_cm": f"{100 * crit.get('min_tol_m', math.nan):g}",
            "max_rot_deg": f"{crit.get('max_rot_deg', math.nan):g}",
        },
        "runs": [
            {
                "label": lbl,
                "path": str(r.path),
                "timestamp": r.run.get("timestamp", ""),
                "verified": (r.dataset.get("verified") is not False),
            }
            for r, lbl in zip(group, dict.fromkeys(table["run"]))
        ],
        "few_trials": bool((table["n_trials"] < MIN_TRIALS_FOR_CI).any()),
        "matrix": _matrix(table),
        "groups": groups,
    }


def _cl_matrix(rows: list[dict], conds: list[str]) -> dict:
    """Localizer x condition of docking success (%, docked/M); the baseline first, then by mean."""
    by: dict[str, dict] = {}
    for r in rows:
        by.setdefault(r["label"], {})[r["condition"]] = r
    out: list[dict[str, Any]] = []
    for label, cells in by.items():
        mean = sum(float(c["success_rate"]) for c in cells.values()) / len(cells)
        out.append(
            {
                "label": label,
                "baseline": any(c.get("baseline") for c in cells.values()),
                "_m": mean,
                "mean": _pct_text(mean),
                "cells": [
                    {
                        "text": f"{_pct_text(cells[c]['success_rate'])} ({cells[c]['n_docked']}/{cells[c]['n_trials']})"
                        if c in cells
                        else "",
                        "shade": _shade(cells[c]["success_rate"]) if c in cells else "#fff",
                    }
                    for c in conds
                ],
            }
        )
    out.sort(key=lambda r: (not r["baseline"], -r["_m"], r["label"]))
    return {"columns": conds, "rows": out}


def _cl_section(group, index: int) -> dict:
    """View model of one closed-loop benchmark (runs with the same config, capture and latency)."""
    from evalkit.reports.closed_loop import CL_COLUMNS, _labelled_rows, rank_rows

    rows = [
        dict(r, success_lo=r.get("ci_low"), success_hi=r.get("ci_high"), full=f"{r['localizer']} ({r['run']})")
        for r in _labelled_rows(group)
    ]
    conds = list(dict.fromkeys(r["condition"] for r in rows))
    groups = []
    for ci, cond in enumerate(conds):
        ranked = rank_rows([r for r in rows if r["condition"] == cond])
        groups.append(
            {
                "title": f"condition {cond}",
                "id": f"cl{index}-{ci}",
                "rows": [
                    {
                        "label": r["label"],
                        "baseline": bool(r.get("baseline")),
                        "cells": [_cell(r, k, kind) for k, _, kind, _ in CL_COLUMNS],
                    }
                    for r in ranked
                ],
            }
        )
    d = group[0].doc
    cam, cap = d["camera"], d["capture"]
    return {
        "name": d["experiment"].get("name"),
        "version": d["experiment"].get("version"),
        "config_hash": str(d["experiment"].get("config_hash") or ""),
        "camera": cam,
        "compute_latency": d.get("compute_latency", 0),
        "fidelity": d.get("fidelity", "?"),
        "capture": cap,
        "runs": [{"label": r.path.name, "path": str(r.path), "timestamp": r.doc.get("timestamp", "")} for r in group],
        "matrix": _cl_matrix(rows, conds),
        "groups": groups,
    }


def build_html(runs: Sequence[Run], title: str = "dockbench leaderboard", closed_loop: Sequence = ()) -> str:
    """The whole page as a string (jinja2, autoescaped): open-loop sections from ``runs``, then
    closed-loop docking sections from ``closed_loop`` (:class:`evalkit.reports.closed_loop.ClosedLoopRun`)."""
    import jinja2

    from evalkit.metrics.extra import MIN_TRIALS_FOR_CI
    from evalkit.reports.results import dockbench_version

    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(Path(__file__).parent / "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
    )
    columns = [
        {"key": k, "header": h, "kind": "text" if kind == "text" else "num", "help": hp} for k, h, kind, hp in COLUMNS
    ]
    from evalkit.reports.closed_loop import CL_COLUMNS, group_closed_loop

    sections = [_section(g, i) for i, g in enumerate(group_runs(runs))] if runs else []
    cl_sections = [_cl_section(g, i) for i, g in enumerate(group_closed_loop(closed_loop))]
    cl_columns = [
        {"key": k, "header": h, "kind": "text" if kind == "text" else "num", "help": hp}
        for k, h, kind, hp in CL_COLUMNS
    ]
    now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    return env.get_template(TEMPLATE).render(
        title=title,
        css=CSS,
        js=JS,
        now=now,
        version=dockbench_version(),
        n_runs=len(runs) + len(closed_loop),
        sections=sections,
        columns=columns,
        min_trials=MIN_TRIALS_FOR_CI,
        cl_sections=cl_sections,
        cl_columns=cl_columns,
    )


def build_leaderboard(result_dirs: Iterable[str | Path], out: str | Path, title: str = "dockbench leaderboard") -> Path:
    """Load the run directories (``dockbench evaluate`` results, or ``dockbench dock`` outputs
    holding a ``closed_loop.json``) and write the HTML page to ``out``."""
    from evalkit.reports.closed_loop import ClosedLoopError, is_closed_loop_dir, load_closed_loop
    from evalkit.reports.results import ResultsError, load_run

    dirs = list(result_dirs)
    if not dirs:
        raise ResultsError("no result directories given")
    try:
        closed = [load_closed_loop(d) for d in dirs if is_closed_loop_dir(d)]
    except ClosedLoopError as exc:
        raise ResultsError(str(exc)) from None
    runs = [load_run(d) for d in dirs if not is_closed_loop_dir(d)]
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(build_html(runs, title, closed), encoding="utf-8")
    return out


# -- headless chromium ---------------------------------------------------------
def find_chromium() -> str | None:
    """Path of a Chromium/Chrome binary, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


def chromium(html_path: str | Path, *args: str, timeout: float = 60.0, fragment: str = "") -> str:
    """Run headless Chromium offline on ``html_path`` with extra ``args``
    (e.g. ``--dump-dom``, ``--screenshot=x.png``); return stdout."""
    exe = find_chromium()
    if exe is None:
        raise RuntimeError("chromium not found (Debian: apt-get install -y chromium)")
    url = Path(html_path).resolve().as_uri() + (f"#{fragment}" if fragment else "")
    with tempfile.TemporaryDirectory(prefix="dockbench-chromium-") as profile:
        cmd = [
            exe,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-dev-shm-usage",
            f"--user-data-dir={profile}",
            *args,
            url,
        ]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"chromium failed ({res.returncode}): {res.stderr.strip()[-500:]}")
    return res.stdout


def screenshot(html_path: str | Path, png: str | Path, size: tuple[int, int] = (1280, 900)) -> Path:
    """Render ``html_path`` to ``png`` with headless Chromium."""
    png = Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    chromium(html_path, f"--screenshot={png}", f"--window-size={size[0]},{size[1]}", "--hide-scrollbars")
    return png
