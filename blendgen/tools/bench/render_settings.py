"""Render settings compared on the same trajectories: image and localization deltas.

Two datasets generated from one config (same seed, so the same camera paths and the same
image-space noise) that differ only in ``render`` settings, e.g. the per-marker ROIs
(``render.roi_regions: markers``) against one box around the dock (``dock``), are compared
frame by frame:

- image: on the marker region (every marker's object-index pixels of the base dataset,
  dilated 3 px: what localizers read) the largest and mean |difference| of the 8-bit
  images (DN) and the PSNR (linear RGB, peak 1); off the markers the mean |difference|;
  by range bin of ``d_true``;
- localization: per localizer, P_succ and E_rel (``evalkit.metrics.core.summarize``) of
  both datasets and their differences, over all frames and by range bin.

Nothing is asserted: the tables are the evidence for choosing a setting
(``dockbench bench render-settings``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from blendgen.tools.bench.fidelity import marker_region

RANGE_BINS = (0.0, 1.0, 2.0, 4.0, 10.0)  # m, d_true edges
LOCALIZERS = ("led", "qr", "aruco")


def _range_bin(d: pd.Series) -> pd.Series:
    return pd.cut(d, RANGE_BINS, right=False).astype(str)


def _frames(ds) -> dict:
    """{(sequence id, frame index): frame record} of a dataset."""
    return {(s["id"], f["index"]): f for s in ds.sequences for f in ds.iter_frames(s["id"])}


def frame_image_deltas(base: np.ndarray, variant: np.ndarray, mask: np.ndarray) -> dict:
    """Deltas of two 8-bit images (H,W,3) on ``mask`` (H,W) bool and off it."""
    a, b = base.astype(np.int16), variant.astype(np.int16)
    d = np.abs(a - b)
    on = d[mask]
    lin = lambda x: np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)  # noqa: E731
    e = (lin(base / 255.0) - lin(variant / 255.0))[mask]
    mse = float(np.mean(e**2)) if e.size else float("nan")
    return {
        "marker_px": int(mask.sum()),
        "marker_max_dn": int(on.max()) if on.size else 0,
        "marker_mean_dn": float(on.mean()) if on.size else float("nan"),
        "marker_psnr_db": float("inf") if mse == 0 else 10 * np.log10(1.0 / mse),
        "off_marker_mean_dn": float(d[~mask].mean()) if (~mask).any() else float("nan"),
    }


def image_table(base_path: Path, variant_path: Path) -> pd.DataFrame:
    """One row per frame present in both datasets (see :func:`frame_image_deltas`)."""
    from datasets_spec.io import load_index
    from evalkit.dataset import Dataset

    b, v = Dataset.open(base_path), Dataset.open(variant_path)
    markers = b.manifest["markers"]
    fb, fv = _frames(b), _frames(v)
    rows = []
    for key in sorted(set(fb) & set(fv)):
        f = fb[key]
        mask = marker_region(load_index(b.frame_file(f, "object_index")), markers)
        rows.append(
            {
                "sequence": key[0],
                "index": key[1],
                "d_true": f["d_true"],
                **frame_image_deltas(b.load_image(f), v.load_image(fv[key]), mask),
            }
        )
    return pd.DataFrame(rows)


def image_summary(df: pd.DataFrame) -> pd.DataFrame:
    """Image deltas by range bin: frames, worst and mean marker DN, median PSNR, off-marker DN."""
    g = df.assign(range_m=_range_bin(df["d_true"])).groupby("range_m", sort=True)
    return g.agg(
        frames=("index", "size"),
        marker_max_dn=("marker_max_dn", "max"),
        marker_mean_dn=("marker_mean_dn", "mean"),
        marker_psnr_db_median=("marker_psnr_db", "median"),
        off_marker_mean_dn=("off_marker_mean_dn", "mean"),
    ).reset_index()


def localization_frames(ds_path: Path, names=LOCALIZERS) -> pd.DataFrame:
    """Scored per-frame table (``evalkit.metrics.core.score_frames``) of ``names``."""
    from evalkit import registry, runner
    from evalkit.dataset import Dataset
    from evalkit.metrics import core as metrics

    ds = Dataset.open(ds_path)
    df = runner.evaluate(ds, [(n, registry.resolve(n, {})) for n in names], progress=False)
    return pd.concat(
        [
            df.drop(columns=[c for c in metrics.SCORE_COLUMNS if c in df.columns]),
            metrics.score_frames(df, None, ds.d_min_rel_m),
        ],
        axis=1,
    )


def _loc_summary(df: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    window = df[df["d_true"] <= 10.0]
    return (
        window.groupby(by, sort=True)
        .agg(
            frames=("success", "size"),
            P_succ=("success", "mean"),
            E_rel_median=("e_rel", "median"),
            E_rel_mean=("e_rel", "mean"),
        )
        .reset_index()
    )


def localization_table(base: pd.DataFrame, variant: pd.DataFrame) -> pd.DataFrame:
    """Per localizer and range bin (and 'all'): P_succ and E_rel of both and their deltas."""
    out = []
    for bin_all in (True, False):
        parts = []
        for df in (base, variant):
            d = df.assign(range_m="all" if bin_all else _range_bin(df["d_true"]))
            parts.append(_loc_summary(d, ["localizer", "range_m"]))
        m = parts[0].merge(parts[1], on=["localizer", "range_m"], suffixes=("_base", "_variant"))
        out.append(m)
    t = pd.concat(out, ignore_index=True)
    t["dP_succ"] = t["P_succ_variant"] - t["P_succ_base"]
    t["dE_rel_median"] = t["E_rel_median_variant"] - t["E_rel_median_base"]
    return t


def run(base: Path, variant: Path, out: Path, echo=print, names=LOCALIZERS) -> None:
    """Print and write (CSV under ``out``) the image and localization deltas."""
    out.mkdir(parents=True, exist_ok=True)
    img = image_table(base, variant)
    img.to_csv(out / "render_settings_images.csv", index=False)
    s = image_summary(img)
    s.to_csv(out / "render_settings_images_by_range.csv", index=False)
    echo(f"image deltas, variant {variant} vs base {base} (8-bit DN; marker region = marker pixels + 3 px):")
    echo(s.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    loc = localization_table(localization_frames(base, names), localization_frames(variant, names))
    loc.to_csv(out / "render_settings_localization.csv", index=False)
    cols = [
        "localizer",
        "range_m",
        "frames_base",
        "P_succ_base",
        "P_succ_variant",
        "dP_succ",
        "E_rel_median_base",
        "E_rel_median_variant",
        "dE_rel_median",
        "E_rel_mean_base",
        "E_rel_mean_variant",
    ]
    echo("\nlocalization (d_true <= 10 m), base vs variant:")
    echo(loc[cols].to_string(index=False, float_format=lambda x: f"{x:.4f}"))
