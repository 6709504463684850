"""Result tables: CSV, Markdown, terminal and LaTeX output of the metrics of
:func:`evalkit.metrics.extra.compute_all` (column names live there and in
:mod:`evalkit.metrics.core`, not here).

LaTeX goes through pandas' ``Styler.to_latex`` (jinja2); ``tabulate`` (needed by
pandas' ``to_markdown``) is not a dependency, so the small Markdown/text formatters
are written here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from datasets_spec.io import BOUNDARY_ENDS
from evalkit.metrics.extra import MIN_TRIALS_FOR_CI


def write_csv(df: pd.DataFrame, path: str | Path) -> Path:
    """Write ``df`` as CSV without the index; floats at full precision, NaN as empty."""
    path = Path(path)
    df.to_csv(path, index=False, lineterminator="\n")
    return path


def format_cell(value, floatfmt: str = ".4g") -> str:
    """Text of one cell: floats with ``floatfmt``, NaN/None as ``"-"``."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        return format(value, floatfmt)
    try:
        if pd.isna(value):
            return "-"
    except (TypeError, ValueError):
        pass
    return str(value)


def _cells(df: pd.DataFrame, floatfmt: str) -> tuple[list[str], list[list[str]]]:
    """Header and body text of a table."""
    header = [str(c) for c in df.columns]
    body = [[format_cell(v, floatfmt) for v in row] for row in df.itertuples(index=False, name=None)]
    return header, body


def _numeric_columns(df: pd.DataFrame) -> list[bool]:
    """Per column: right-align (numeric, not bool)?"""
    return [pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c]) for c in df.columns]


def _widths(header: Sequence[str], body: Sequence[Sequence[str]]) -> list[int]:
    """Max text width per column."""
    return [max([len(h)] + [len(r[i]) for r in body]) for i, h in enumerate(header)]


def _pad(text: str, width: int, right: bool) -> str:
    """Pad to ``width``, right-aligned if ``right``."""
    return text.rjust(width) if right else text.ljust(width)


def to_markdown(df: pd.DataFrame, floatfmt: str = ".4g") -> str:
    """GitHub-flavoured Markdown table (numeric columns right-aligned)."""
    header, body = _cells(df, floatfmt)
    widths = [max(w, 3) for w in _widths(header, body)]
    right = _numeric_columns(df)

    def line(cells):
        return "| " + " | ".join(_pad(c.replace("|", "\\|"), w, r) for c, w, r in zip(cells, widths, right)) + " |"

    rule = "|" + "|".join(("-" * (w + 1) + ":") if r else (":" + "-" * (w + 1)) for w, r in zip(widths, right)) + "|"
    return "\n".join([line(header), rule] + [line(r) for r in body]) + "\n"


def to_text(df: pd.DataFrame, floatfmt: str = ".4g") -> str:
    """Plain aligned table for a terminal."""
    header, body = _cells(df, floatfmt)
    widths = _widths(header, body)
    right = _numeric_columns(df)

    def line(cells):
        return "  ".join(_pad(c, w, r) for c, w, r in zip(cells, widths, right)).rstrip()

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([line(header), rule] + [line(r) for r in body]) + "\n"


def print_table(df: pd.DataFrame, floatfmt: str = ".4g", file=None) -> None:
    """Print :func:`to_text` (to stdout by default)."""
    print(to_text(df, floatfmt), end="", file=file)


_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}


def latex_escape(text: str) -> str:
    """Escape LaTeX special characters (for captions; cells go through pandas' own escaping)."""
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in text)


def to_latex(
    df: pd.DataFrame,
    floatfmt: str = ".4g",
    caption: str | None = None,
    label: str | None = None,
    column_format: str | None = None,
) -> str:
    """A ``booktabs`` tabular by pandas' ``Styler.to_latex`` (cells and headers LaTeX-escaped;
    numbers right-aligned unless ``column_format``), in a ``table`` float when
    ``caption``/``label`` is given."""
    spec = column_format or "".join("r" if r else "l" for r in _numeric_columns(df))
    text = df.astype(object).map(lambda v: format_cell(v, floatfmt))
    styler = text.style.hide(axis="index").format(escape="latex").format_index(escape="latex", axis=1)
    kw = {"hrules": True, "column_format": spec}
    if caption is not None or label is not None:
        kw.update(
            position="t", position_float="centering", label=label, caption=latex_escape(caption) if caption else None
        )
    return styler.to_latex(**kw)


# -- the article's table shape --------------------------------------------------
ARTICLE_SUCCESS = "P_succ (%)"
ARTICLE_DETECT = "P_detect (%)"
ARTICLE_ERROR = "E_rel (%)"
ARTICLE_MATCHED = "E_rel matched (%)"
ARTICLE_MATCHED_RANGE = "matched bins"
MATCHED_NOTE = (
    "E_rel pools every frame a condition answers; E_rel matched averages the 1 m bins that "
    "every condition of the trajectory answers in (each bin weighted equally), so conditions "
    "are compared at the same ranges."
)
FEW_TRIALS_NOTE = (
    f"* M < {MIN_TRIALS_FOR_CI} trials: the bootstrap CI is unreliable "
    "(M = 1: no CI at all); generate more trials (config `trials:`)."
)


def _pct(value, lo=None, hi=None, digits: int = 1) -> str:
    """``12.3`` or ``12.3 [11.0, 13.9]`` (fractions shown in percent); ``-`` for NaN.

    Value and bounds are rounded to the same number of digits: rounding is monotonic, so
    a mean inside its CI is printed inside it (the old table printed the bounds with one
    digit less, which could put the mean outside)."""
    if value is None or pd.isna(value):
        return "-"
    text = f"{100 * float(value):.{digits}f}"
    if lo is not None and hi is not None and not (pd.isna(lo) or pd.isna(hi)):
        text += f" [{100 * float(lo):.{digits}f}, {100 * float(hi):.{digits}f}]"
    return text


def article_table(metrics: pd.DataFrame, with_ci: bool = True, digits: int = 1) -> pd.DataFrame:
    """One row per (trajectory, condition, localizer): ``M`` (trials, ``*`` below
    :data:`MIN_TRIALS_FOR_CI`), :data:`ARTICLE_SUCCESS`, :data:`ARTICLE_DETECT`,
    :data:`ARTICLE_ERROR` in percent with the bootstrap CI in brackets (text cells), and
    beside the pooled error the range-matched one (:data:`ARTICLE_MATCHED`) with its bins.
    ``metrics`` is :func:`evalkit.metrics.extra.compute_all`'s ``metrics`` table."""
    rows = []
    err_digits = max(digits, 2)  # relative errors of a few tenths of a percent need two decimals
    order = metrics.sort_values(["trajectory", "condition", "localizer"], kind="stable")
    for _, r in order.iterrows():

        def cell(mean_col, prefix, nd=digits):
            lo, hi = (r.get(f"{prefix}_lo"), r.get(f"{prefix}_hi")) if with_ci else (None, None)
            return _pct(r.get(mean_col), lo, hi, nd)

        m = int(r["n_trials"])
        rows.append(
            {
                "trajectory": r["trajectory"],
                "condition": r["condition"],
                "localizer": r["localizer"],
                "M": f"{m}*" if m < MIN_TRIALS_FOR_CI else str(m),
                ARTICLE_SUCCESS: cell("P_succ_mean", "P_succ"),
                ARTICLE_DETECT: cell("P_detect_mean", "P_detect"),
                ARTICLE_ERROR: cell("E_rel_mean", "E_rel", err_digits),
                ARTICLE_MATCHED: _pct(r.get("E_rel_matched"), digits=err_digits),
                ARTICLE_MATCHED_RANGE: _bins_text(r),
            }
        )
    return pd.DataFrame(
        rows,
        columns=[
            "trajectory",
            "condition",
            "localizer",
            "M",
            ARTICLE_SUCCESS,
            ARTICLE_DETECT,
            ARTICLE_ERROR,
            ARTICLE_MATCHED,
            ARTICLE_MATCHED_RANGE,
        ],
    )


def _bins_text(r) -> str:
    """``"2-7 m (5)"``: extent and number of the matched bins of a metrics row; ``-`` if none."""
    n, lo, hi = r.get("n_matched_bins"), r.get("matched_lo_m"), r.get("matched_hi_m")
    if n is None or pd.isna(n) or not n or pd.isna(lo) or pd.isna(hi):
        return "-"
    return f"{float(lo):g}-{float(hi):g} m ({int(n)})"


def _few(metrics: pd.DataFrame) -> bool:
    return bool(len(metrics)) and bool((metrics["n_trials"] < MIN_TRIALS_FOR_CI).any())


def article_markdown(metrics: pd.DataFrame, with_ci: bool = True, sequences: list[dict] | None = None) -> str:
    """:func:`article_table` as Markdown, one table per trajectory (never pooled); with the
    manifest's ``sequences``, a note on the trials that ended at the water's boundary
    (:func:`boundary_end_note`)."""
    art = article_table(metrics, with_ci)
    parts = []
    for traj, g in art.groupby("trajectory", sort=True):
        parts.append(f"### trajectory {traj or '(unnamed)'}\n\n" + to_markdown(g.drop(columns="trajectory")))
    parts.append(MATCHED_NOTE + "\n")
    if _few(metrics):
        parts.append(FEW_TRIALS_NOTE + "\n")
    ends = boundary_end_note(sequences or [])
    if ends:
        parts.append(ends + "\n")
    return "\n".join(parts)


def boundary_end_note(sequences: list[dict]) -> str:
    """One line naming, per trajectory/condition, how many trials ended where the vehicle's
    hull touched the pool's walls or floor or the seabed (manifest ``sequences[].end``,
    spec_version 1.2: a current carried it there); "" when none did (or the dataset predates
    the field). Their frames stop at the touch, so their P_succ and E_rel cover only the
    ranges they reached."""
    groups: dict[tuple[str, str], list[str]] = {}
    for s in sequences:
        groups.setdefault((str(s.get("trajectory")), str(s.get("condition"))), []).append(str(s.get("end", "")))
    hits = []
    for (traj, cond), ends in sorted(groups.items()):
        parts = sorted({e for e in ends if e in BOUNDARY_ENDS})
        if parts:
            n = sum(e in BOUNDARY_ENDS for e in ends)
            hits.append(f"{traj}/{cond} {n} of {len(ends)} ({', '.join(parts)})")
    if not hits:
        return ""
    return (
        "Trials that ended where the vehicle's hull touched the water's boundary, before the dock "
        "(their frames stop there, so their P_succ and E_rel cover only the ranges they reached): "
        + "; ".join(hits)
        + "."
    )


def article_latex(
    metrics: pd.DataFrame, with_ci: bool = True, caption: str | None = None, label: str | None = None
) -> str:
    """:func:`article_table` as a LaTeX ``booktabs`` tabular (``%`` escaped); a footnote
    row when some group has fewer than :data:`MIN_TRIALS_FOR_CI` trials."""
    df = article_table(metrics, with_ci)
    out = to_latex(df, caption=caption, label=label, column_format="lllrrrrrl")
    if _few(metrics):
        note = latex_escape(FEW_TRIALS_NOTE)
        out = out.replace(
            r"\bottomrule", r"\bottomrule" + "\n" + rf"\multicolumn{{9}}{{l}}{{\footnotesize {note}}} \\", 1
        )
    return out


# -- per range bin ------------------------------------------------------------------
def range_bin_table(bins: pd.DataFrame, localizer: str, trajectory: str) -> pd.DataFrame:
    """One row per condition of (``localizer``, ``trajectory``), one column per distance
    bin that holds frames: ``"P_succ / E_rel"`` in percent (``-`` where a condition has no
    frame or no estimate). ``bins`` is :func:`evalkit.metrics.extra.distance_bins`'s table."""
    b = bins[(bins["localizer"] == localizer) & (bins["trajectory"] == trajectory)]
    used = sorted(b.loc[b["n_total"] > 0, "bin_lo"].unique())
    rows = []
    for cond, g in b.groupby("condition", sort=True, dropna=False):
        row = {"condition": cond}
        for _, r in g[g["bin_lo"].isin(used)].sort_values("bin_lo").iterrows():
            key = f"{r['bin_lo']:g}-{r['bin_hi']:g} m"
            if r["n_total"] <= 0:
                row[key] = "-"
                continue
            err = "-" if pd.isna(r["e_rel_mean"]) else f"{100 * r['e_rel_mean']:.2f}"
            row[key] = f"{100 * r['P_succ']:.0f} / {err}"
        rows.append(row)
    return pd.DataFrame(rows)


def range_bins_markdown(bins: pd.DataFrame) -> str:
    """Per (trajectory, localizer) a :func:`range_bin_table` as Markdown: success and error
    against range for every condition, which separates what water does at a given range
    from which ranges a condition keeps."""
    parts = [
        "P_succ (%) / E_rel (%) per 1 m bin of d_true (frames of all trials pooled; "
        "E_rel over the frames with an estimate)\n"
    ]
    for (traj, loc), _ in bins.groupby(["trajectory", "localizer"], sort=True, dropna=False):
        table = range_bin_table(bins, loc, traj)
        if len(table):
            parts.append(f"### {traj or '(unnamed)'}: {loc}\n\n" + to_markdown(table))
    return "\n".join(parts)
