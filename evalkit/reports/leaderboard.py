"""A single static HTML leaderboard from result directories (no server, no internet).

``dockbench leaderboard RESULTS_DIR... -o board.html``: runs are grouped by the
dataset content they were computed on (``content_hash``; runs on different
data are never ranked together), then per condition the localizers are ranked
by ``P_succ_mean`` (descending), ties by ``E_rel_mean`` (ascending). 95 %
bootstrap CIs over trials are shown in brackets and as whiskers in an inline SVG
chart. Inline CSS and a little inline JS (click a header to sort; the URL
fragment ``#sort=<column>&dir=asc|desc`` sorts every table on load).
"""
from __future__ import annotations

import datetime as _dt
import html
import math
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Sequence

import click

if TYPE_CHECKING:
    import pandas as pd

    from evalkit.reports.results import Run

# pandas and evalkit.reports.results are imported inside the functions so that wiring
# ``leaderboard_cmd`` into the CLI keeps ``dockbench --help`` fast.

# (key, header, kind): kind "pct" = fraction shown in %, "num" = plain number, "text"
COLUMNS: list[tuple[str, str, str]] = [
    ("rank", "#", "int"),
    ("label", "localizer", "text"),
    ("run", "run", "text"),
    ("P_succ_mean", "P_succ (%)", "pct_ci"),
    ("E_rel_mean", "E_rel (%)", "pct_ci"),
    ("e_abs_mean", "e_abs (m)", "num"),
    ("e_trans_mean", "e_trans (m)", "num"),
    ("e_rot_deg_mean", "e_rot (deg)", "num"),
    ("e_lateral_mean", "lateral (m)", "num"),
    ("e_range_abs_mean", "range (m)", "num"),
    ("fp_rate", "FP rate (%)", "pct"),
    ("max_range_m", "usable range (m)", "num"),
    ("ms_median", "ms median", "num"),
    ("ms_p95", "ms p95", "num"),
    ("n_trials", "trials", "int"),
]
CI_PREFIX = {"P_succ_mean": "P_succ", "E_rel_mean": "E_rel"}

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:24px;color:#1b1f24;background:#fff}
h1{font-size:22px;margin:0 0 4px}h2{font-size:18px;margin:28px 0 4px;border-bottom:2px solid #d0d7de;padding-bottom:4px}
h3{font-size:15px;margin:18px 0 6px}.meta{color:#57606a;font-size:12px}
table.lb{border-collapse:collapse;font-size:13px;margin:6px 0 4px}
table.lb th,table.lb td{border:1px solid #d0d7de;padding:3px 8px;white-space:nowrap}
table.lb th{background:#f6f8fa;cursor:pointer;user-select:none}
table.lb th.sorted-asc::after{content:" \\25B2"}table.lb th.sorted-desc::after{content:" \\25BC"}
table.lb td.n{text-align:right;font-variant-numeric:tabular-nums}
table.lb tr:nth-child(even) td{background:#fbfcfd}
table.lb tr.first td{background:#eaf5ea}
.ci{color:#6e7781;font-size:11px}.cond{display:flex;flex-wrap:wrap;gap:18px;align-items:flex-start}
svg text{font-family:inherit;font-size:11px}code{font-size:12px}
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


def _cell(row: pd.Series, key: str, kind: str) -> str:
    """One ``<td>`` with a ``data-v`` sort value."""
    v = row.get(key)
    if kind == "text":
        t = html.escape(str(v))
        return f'<td data-v="{t}">{t}</td>'
    if not _finite(v):
        return '<td class="n" data-v="">-</td>'
    f = float(v)
    if kind == "int":
        return f'<td class="n" data-v="{f:g}">{int(f)}</td>'
    if kind == "num":
        return f'<td class="n" data-v="{f:.9g}">{f:.3g}</td>'
    text = f"{100 * f:.1f}"
    if kind == "pct_ci":
        p = CI_PREFIX[key]
        lo, hi = row.get(f"{p}_lo"), row.get(f"{p}_hi")
        if _finite(lo) and _finite(hi):
            text += f' <span class="ci">[{100 * float(lo):.1f}, {100 * float(hi):.1f}]</span>'
    return f'<td class="n" data-v="{f:.9g}">{text}</td>'


def rank(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of one (dataset, condition) sorted by ``P_succ_mean`` desc, ``E_rel_mean`` asc,
    with a ``rank`` column (1 = best; NaN metrics last)."""
    key_p = -df["P_succ_mean"].astype(float).fillna(-math.inf)
    key_e = df["E_rel_mean"].astype(float).fillna(math.inf)
    out = df.assign(_p=key_p, _e=key_e).sort_values(["_p", "_e", "label"], kind="stable")
    out = out.drop(columns=["_p", "_e"]).reset_index(drop=True)
    out.insert(0, "rank", range(1, len(out) + 1))
    return out


def svg_chart(df: pd.DataFrame, width: int = 360) -> str:
    """Inline SVG: horizontal ``P_succ`` bars with CI whiskers, one per ranked row."""
    bar_h, gap, left, right, top = 16, 6, 120, 44, 18
    height = top + len(df) * (bar_h + gap) + 18
    plot_w = width - left - right
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'role="img" aria-label="P_succ chart">',
             f'<text x="{left}" y="12" fill="#57606a">P_succ (%) with 95% CI</text>']
    for tick in (0, 50, 100):
        x = left + plot_w * tick / 100
        parts.append(f'<line x1="{x:.1f}" y1="{top - 2}" x2="{x:.1f}" y2="{height - 16}" stroke="#d0d7de"/>'
                     f'<text x="{x:.1f}" y="{height - 4}" text-anchor="middle" fill="#57606a">{tick}</text>')
    for i, (_, r) in enumerate(df.iterrows()):
        y = top + i * (bar_h + gap)
        p = float(r["P_succ_mean"]) if _finite(r.get("P_succ_mean")) else 0.0
        name = html.escape(str(r["label"]))[:18]
        parts.append(f'<text x="{left - 6}" y="{y + bar_h - 4}" text-anchor="end">{name}</text>')
        parts.append(f'<rect x="{left}" y="{y}" width="{plot_w * p:.1f}" height="{bar_h}" '
                     f'fill="{"#2da44e" if i == 0 else "#54aeff"}"/>')
        lo, hi = r.get("P_succ_lo"), r.get("P_succ_hi")
        end = max(p, float(hi)) if _finite(hi) else p
        parts.append(f'<text x="{left + plot_w * end + 5:.1f}" y="{y + bar_h - 4}">{100 * p:.0f}</text>')
        if _finite(lo) and _finite(hi):
            x0, x1, ym = left + plot_w * float(lo), left + plot_w * float(hi), y + bar_h / 2
            parts.append(f'<path d="M{x0:.1f} {ym - 4}v8M{x0:.1f} {ym}H{x1:.1f}M{x1:.1f} {ym - 4}v8" '
                         f'stroke="#1b1f24" stroke-width="1.2" fill="none"/>')
    parts.append("</svg>")
    return "".join(parts)


def _table(df: pd.DataFrame, table_id: str) -> str:
    """The ranked rows of one condition as a sortable table."""
    head = "".join(f'<th data-col="{k}" data-kind="{"text" if kind == "text" else "num"}">'
                   f'{html.escape(h)}</th>' for k, h, kind in COLUMNS)
    rows = []
    for i, (_, r) in enumerate(df.iterrows()):
        cls = "lb-row first" if i == 0 else "lb-row"
        cells = "".join(_cell(r, k, kind) for k, _, kind in COLUMNS)
        rows.append(f'<tr class="{cls}" data-localizer="{html.escape(str(r["label"]))}">{cells}</tr>')
    return (f'<table class="lb" id="{table_id}"><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(rows)}</tbody></table>')


def group_runs(runs: Sequence[Run]) -> list[list[Run]]:
    """Runs grouped by dataset ``content_hash`` (order of first appearance)."""
    from evalkit.reports.results import ResultsError
    groups: dict[str, list[Run]] = {}
    for r in runs:
        if not r.content_hash:
            raise ResultsError(f"{r.path}: run.json has no dataset content_hash")
        groups.setdefault(r.content_hash, []).append(r)
    return list(groups.values())


def build_html(runs: Sequence[Run], title: str = "dockbench leaderboard") -> str:
    """The whole page as a string."""
    from evalkit.reports.results import compare_runs, dockbench_version
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    body = [f"<h1>{html.escape(title)}</h1>",
            f'<p class="meta">generated {now} by dockbench {html.escape(dockbench_version())} '
            f"from {len(runs)} run(s). Ranked per condition by P_succ (desc), ties by E_rel (asc); "
            "brackets: 95% bootstrap CI over trials. Click a header to sort.</p>"]
    for gi, group in enumerate(group_runs(runs)):
        table = compare_runs(group)
        ds = group[0].dataset
        body.append(f'<section class="dataset" data-content-hash="{html.escape(ds.get("content_hash", ""))}">'
                    f'<h2>dataset {html.escape(str(ds.get("name")))} {html.escape(str(ds.get("version")))}</h2>'
                    f'<p class="meta">content_hash <code>{html.escape(ds.get("content_hash", ""))}</code>; runs: '
                    + ", ".join(f'<code>{html.escape(r.label)}</code> ({html.escape(str(r.run.get("timestamp", "")))})'
                                for r in group) + "</p>")
        for ci, (cond, g) in enumerate(table.groupby("condition", sort=True)):
            ranked = rank(g)
            body.append(f'<h3>condition: {html.escape(str(cond))}</h3><div class="cond">'
                        f'{_table(ranked, f"t{gi}-{ci}")}{svg_chart(ranked)}</div>')
        body.append("</section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head>"
            f"<body>{''.join(body)}<script>{JS}</script></body></html>\n")


def build_leaderboard(result_dirs: Iterable[str | Path], out: str | Path,
                      title: str = "dockbench leaderboard") -> Path:
    """Load the run directories and write the HTML page to ``out``."""
    from evalkit.reports.results import ResultsError, load_run
    runs = [load_run(d) for d in result_dirs]
    if not runs:
        raise ResultsError("no result directories given")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(build_html(runs, title), encoding="utf-8")
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
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--disable-dev-shm-usage", f"--user-data-dir={profile}", *args, url]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"chromium failed ({res.returncode}): {res.stderr.strip()[-500:]}")
    return res.stdout


def screenshot(html_path: str | Path, png: str | Path, size: tuple[int, int] = (1400, 900)) -> Path:
    """Render ``html_path`` to ``png`` with headless Chromium."""
    png = Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    chromium(html_path, f"--screenshot={png}", f"--window-size={size[0]},{size[1]}",
             "--hide-scrollbars")
    return png


@click.command("leaderboard")
@click.argument("results_dirs", nargs=-1, required=True,
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False, path_type=Path),
              default=Path("leaderboard.html"), show_default=True, help="HTML file to write")
@click.option("--title", default="dockbench leaderboard", show_default=True)
@click.option("--screenshot", "shot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="also render the page to this PNG (needs chromium)")
def leaderboard_cmd(results_dirs: tuple[Path, ...], out: Path, title: str, shot: Path | None):
    """Rank localizers per dataset and condition from RESULTS_DIRS (of `dockbench evaluate`)
    into one static HTML page."""
    from evalkit.reports.results import ResultsError
    try:
        path = build_leaderboard(results_dirs, out, title)
    except ResultsError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    click.echo(f"leaderboard: {path}")
    if shot is not None:
        try:
            click.echo(f"screenshot: {screenshot(path, shot)}")
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            click.echo(f"error: screenshot: {exc}", err=True)
            sys.exit(2)
