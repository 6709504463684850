"""Result tables: CSV, Markdown, terminal and LaTeX output.

No optional dependencies: ``tabulate`` and ``jinja2`` (needed by pandas'
``to_markdown`` / ``to_latex``) are not installed, so the formatters are
written here.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import pandas as pd

from evalkit.metrics import core as metrics

SUMMARY_COLUMNS = ["localizer", "sequence", "condition", "n_total", "n_succ", "P_succ",
                   "e_abs_mean", "e_rel_mean"]
CONDITION_COLUMNS = ["localizer", "condition", "n_trials", "P_succ_mean", "E_rel_mean"]


def summary_table(estimates: pd.DataFrame, d_max: float = metrics.D_MAX_M,
                  d_min_rel: float = metrics.D_MIN_REL_M) -> pd.DataFrame:
    """Per-trial table with exactly :data:`SUMMARY_COLUMNS` (see :func:`metrics.per_trial`)."""
    return metrics.per_trial(estimates, d_max, d_min_rel)[SUMMARY_COLUMNS]


def condition_table(summary: pd.DataFrame) -> pd.DataFrame:
    """Per-condition table with exactly :data:`CONDITION_COLUMNS` (see :func:`metrics.per_condition`)."""
    return metrics.per_condition(summary)[CONDITION_COLUMNS]


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
    return [pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c])
            for c in df.columns]


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
        return "| " + " | ".join(_pad(c.replace("|", "\\|"), w, r)
                                 for c, w, r in zip(cells, widths, right)) + " |"
    rule = "|" + "|".join(("-" * (w + 1) + ":") if r else (":" + "-" * (w + 1))
                          for w, r in zip(widths, right)) + "|"
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


_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
                  "^": r"\textasciicircum{}"}


def latex_escape(text: str) -> str:
    """Escape LaTeX special characters."""
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in text)


def to_latex(df: pd.DataFrame, floatfmt: str = ".4g", caption: str | None = None,
             label: str | None = None) -> str:
    """A ``booktabs`` tabular (wrapped in a table float if ``caption``/``label`` is given)."""
    header, body = _cells(df, floatfmt)
    spec = "".join("r" if r else "l" for r in _numeric_columns(df))
    rows = [" & ".join(latex_escape(c) for c in header) + r" \\", r"\midrule"]
    rows += [" & ".join(latex_escape(c) for c in r) + r" \\" for r in body]
    tabular = "\n".join([rf"\begin{{tabular}}{{{spec}}}", r"\toprule", *rows, r"\bottomrule",
                         r"\end{tabular}"])
    if caption is None and label is None:
        return tabular + "\n"
    parts = [r"\begin{table}[t]", r"\centering"]
    if caption:
        parts.append(rf"\caption{{{latex_escape(caption)}}}")
    if label:
        parts.append(rf"\label{{{label}}}")
    return "\n".join(parts + [tabular, r"\end{table}"]) + "\n"


# -- the article's table shape --------------------------------------------------
ARTICLE_ERROR = "average positioning error (%)"
ARTICLE_SUCCESS = "successful docking location rate (%)"


def _pct(value, lo=None, hi=None, digits: int = 2) -> str:
    """``12.34`` or ``12.34 [11.0, 13.9]`` (fractions shown in percent); ``-`` for NaN."""
    if value is None or pd.isna(value):
        return "-"
    text = f"{100 * float(value):.{digits}f}"
    if lo is not None and hi is not None and not (pd.isna(lo) or pd.isna(hi)):
        text += f" [{100 * float(lo):.{max(digits - 1, 0)}f}, {100 * float(hi):.{max(digits - 1, 0)}f}]"
    return text


def article_table(conditions: pd.DataFrame, with_ci: bool = True, digits: int = 2) -> pd.DataFrame:
    """The article's table: one row per (localizer, condition) with
    :data:`ARTICLE_ERROR` (``E_rel_mean``) and :data:`ARTICLE_SUCCESS` (``P_succ_mean``),
    both in percent, text cells. With ``with_ci`` and the ``*_lo``/``*_hi`` columns of
    :func:`evalkit.metrics.extra.compute_all`, the 95 % bootstrap CI follows in brackets.
    Accepts :func:`condition_table` output as well (no CIs then).
    """
    def ci(row, prefix):
        if not with_ci:
            return None, None
        return row.get(f"{prefix}_lo"), row.get(f"{prefix}_hi")

    rows = []
    for _, r in conditions.iterrows():
        rows.append({"localizer": r["localizer"], "condition": r["condition"],
                     ARTICLE_ERROR: _pct(r["E_rel_mean"], *ci(r, "E_rel"), digits=digits),
                     ARTICLE_SUCCESS: _pct(r["P_succ_mean"], *ci(r, "P_succ"), digits=digits)})
    return pd.DataFrame(rows, columns=["localizer", "condition", ARTICLE_ERROR, ARTICLE_SUCCESS])


def article_markdown(conditions: pd.DataFrame, with_ci: bool = True) -> str:
    """:func:`article_table` as Markdown."""
    return to_markdown(article_table(conditions, with_ci))


def article_latex(conditions: pd.DataFrame, with_ci: bool = True, caption: str | None = None,
                  label: str | None = None) -> str:
    """:func:`article_table` as a LaTeX ``booktabs`` tabular (``%`` escaped)."""
    df = article_table(conditions, with_ci)
    # text cells are left-aligned by to_latex; numbers are right-aligned in the article
    out = to_latex(df, caption=caption, label=label)
    return out.replace(r"\begin{tabular}{llll}", r"\begin{tabular}{llrr}", 1)
