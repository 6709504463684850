"""The turbidity ladder's report: where each localizer's usable range ends per water, next to
the contrast-threshold prediction of :mod:`blendgen.physics.water.visibility` (docs/waters.md).

The prediction uses the experiment's own numbers: the condition's water in its image
formation (coefficients and the veil the fast model composes with), the downwelling
irradiance, the dock's depth, LED intensities and colours, code sizes, camera focal length.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from blendgen.physics.water import optics, visibility
from blendgen.pipeline import plan
from blendgen.vehicle.trajectories import dock_top_m

#: Printed black and white albedo of the square markers, as the renderer's materials
#: (blendgen/blender/materials.py PRINT_BLACK, PRINT_WHITE).
PRINT_BLACK, PRINT_WHITE = 0.04, 0.85
#: Irradiance on the vertical dock face as a share of the downwelling irradiance at its
#: depth: 1/2, a vertical plane in a light field whose radiance is symmetric about the
#: vertical (our approximation; the sun's direction changes it by up to cot(elevation)).
VERTICAL_FACE_SHARE = 0.5


def _water_and_veil(exp, cond, depth_m: float):
    """(WaterOptics, veiling radiance (3,) W/m^2/sr at the dock's depth, horizontal view)."""
    spec = cond.water or exp.water
    E0 = plan.downwelling_irradiance(exp)
    veil = optics.veil_parameters(spec, exp.image_formation)
    water, opts = optics.fast_water(spec, exp.image_formation, E0, veil=veil)
    if opts.get("veil"):
        share = 1.0 / (1.0 + plan.sky_fraction(exp))
        B = optics.veil_radiance_at(water, opts["veil"], depth_m, 0.0, exp.scene.sun_elevation_deg, share)
        return water, B * E0
    return water, water.B_inf * opts["irradiance"] * optics.depth_light(water, depth_m)


def _cell_m(m) -> float:
    """Side (m) of one code cell of a square marker."""
    if m["kind"] == "qr":
        return float(m["module_size_m"])
    import cv2

    n = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, m["dictionary"])).markerSize + 2
    return float(m["size_m"]) / n


def predict(exp, cond) -> dict:
    """Predicted usable range (m) per marker id of one condition, plus ``ref_led_red_m`` (the
    reference LED's red channel alone) and the water's ``c`` (3,)."""
    depth = cond.dock_water_depth_m if cond.dock_water_depth_m is not None else exp.scene.dock.water_depth_m
    depth += dock_top_m(exp.scene.dock)  # the face centre's depth
    water, L_inf = _water_and_veil(exp, cond, depth)
    E_face = plan.downwelling_irradiance(exp) * optics.depth_light(water, depth) * VERTICAL_FACE_SHARE
    L_face = np.asarray(exp.scene.dock.face_color, float) * E_face / math.pi
    f_px = float(plan.camera_K(exp)[0, 0])
    out = {"c": water.c.tolist()}
    for m in plan.manifest_markers(exp):
        if m["kind"] == "led_array":
            ranges = [
                visibility.led_range_m(
                    np.asarray(col) * m["intensity_w_sr"], m["led_radius_m"], L_face, L_inf, water.c, f_px
                )
                for col in m["colors"]
            ]
            out[m["id"]] = min(ranges)
            ref = np.asarray(m["colors"][m["reference_index"]]) * m["intensity_w_sr"] * [1.0, 0.0, 0.0]
            out["ref_led_red_m"] = visibility.led_range_m(ref, m["led_radius_m"], L_face, L_inf, water.c, f_px)
        else:
            out[m["id"]] = visibility.square_marker_range_m(
                _cell_m(m), PRINT_WHITE * E_face / math.pi, PRINT_BLACK * E_face / math.pi, L_inf, water.c, f_px
            )["range_m"]
    return out


#: Which marker each localizer reads (hybrid: the LED array, the farther-reaching one).
LOCALIZER_MARKER = {"led": "led", "qr": "qr", "aruco": "aruco", "hybrid": "led"}


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    top = float(visibility.RANGE_GRID_M[-1])
    return f">{top:.0f}" if v >= top - 0.02 else f"{v:.1f}"


def ladder_table(exp, metrics: pd.DataFrame) -> str:
    """Markdown table: per water, c (R/G/B), the predicted range of each marker and the
    measured usable range (largest 1 m bin with P_succ >= 0.9) of each localizer."""
    locs = [n for n in LOCALIZER_MARKER if n in set(metrics["localizer"])]
    head = ["water", "c R/G/B (1/m)"] + [f"{n} pred / meas (m)" for n in locs] + ["red ref LED pred (m)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cond in exp.conditions:
        p = predict(exp, cond)
        row = [cond.label, "/".join(f"{x:.2f}" for x in p["c"])]
        for n in locs:
            sel = metrics[(metrics["localizer"] == n) & (metrics["condition"] == cond.label)]["max_range_m"]
            meas = float(sel.max()) if len(sel) and sel.notna().any() else None
            row.append(f"{_fmt(p.get(LOCALIZER_MARKER[n]))} / {_fmt(meas)}")
        row.append(_fmt(p.get("ref_led_red_m")))
        lines.append("| " + " | ".join(row) + " |")
    far = (
        max(t.start.range_m[1] for t in exp.trajectories if t.kind == "docking")
        if any(t.kind == "docking" for t in exp.trajectories)
        else None
    )
    note = (
        f"predicted: contrast threshold {visibility.CONTRAST_THRESHOLD:g} (Duntley), code cells >= "
        f"{visibility.MIN_PX_PER_CELL:g} px; measured: largest 1 m bin with P_succ >= 0.9"
        + (f" (the paths start at most {far:g} m away: a measured range at the start is a lower bound)" if far else "")
    )
    return "\n".join(lines + ["", note])
