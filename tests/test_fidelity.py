"""Fast-model calibration, the fidelity bench's pure parts, preview, and their commands."""

import json
import sys

import numpy as np
import pytest

from blendgen.config.models import Water
from blendgen.physics.water import optics
from blendgen.tools.bench import fidelity

CAL = {"method": "test", "presets": {"moderate": {"B_inf": [0.01, 0.02, 0.03], "Kd": [0.3, 0.3, 0.3], "blur": False}}}


def test_fit_condition_recovers_direct_scale_and_veiling_light():
    rng = np.random.default_rng(0)
    c = np.array([0.5, 0.3, 0.2])
    a_true, B_true = np.array([0.6, 0.7, 0.8]), np.array([0.01, 0.05, 0.03])
    samples = []
    for _ in range(3):
        J = rng.uniform(0.05, 0.3, (500, 3))
        r = rng.uniform(0.5, 10.0, 500)
        t = np.exp(-c * r[:, None])
        samples.append((a_true * J * t + B_true * (1 - t), J, r))
    a, B = fidelity.fit_condition(samples, c)
    assert np.allclose(a, a_true, rtol=1e-9) and np.allclose(B, B_true, rtol=1e-9)


def test_image_errors():
    ref = np.full((20, 30, 3), 0.5)
    mask = np.zeros((20, 30), bool)
    mask[5:10, 5:10] = True
    psnr, mae = fidelity.image_errors(ref + 0.01, ref, mask)
    assert mae == pytest.approx(0.01) and psnr == pytest.approx(40.0)
    assert fidelity.image_errors(ref.copy(), ref, mask) == (float("inf"), 0.0)
    half = np.full((10, 15, 3), 0.5)  # other resolution: the reference is resized
    assert fidelity.image_errors(half, ref, mask)[1] == pytest.approx(0.0)


def test_srgb_round_trip():
    x = np.arange(256, dtype=np.uint8)
    lin = fidelity.srgb_to_linear(x)
    assert lin[0] == 0 and lin[-1] == pytest.approx(1.0) and np.all(np.diff(lin) > 0)


def test_fast_water_veil_per_mode_and_calibration():
    # a bare physical moderate is Jerlov II: calibrated under that name
    cal = {**CAL, "presets": {"jerlov_II": CAL["presets"]["moderate"]}, "sun_elevation_deg": 30.0}
    w, fo = optics.fast_water(Water(preset="moderate", calibrated=True), "physical", 3.0, cal)
    assert fo["calibrated"] and fo["irradiance"] == 3.0
    assert np.allclose(w.B_inf, np.array([0.01, 0.02, 0.03]) / 0.5)  # per unit sun -> per unit E_d
    assert np.allclose(w.c, optics.get_preset("jerlov_II").c)  # c is never calibrated
    assert np.allclose(w.Kd, optics.get_preset("jerlov_II").Kd)  # physical: moderate -> Jerlov II
    w2, fo2 = optics.fast_water(Water(preset="moderate"), "physical", 3.0, cal)  # default: light field
    assert not fo2["calibrated"]
    assert np.allclose(w2.B_inf, w2.albedo / (4 * np.pi * optics.MEAN_COSINE_DOWN))
    w3, fo3 = optics.fast_water(Water(preset="moderate", beta=0.4, calibrated=True), "physical", 3.0, cal)
    assert not fo3["calibrated"]  # not a bare preset
    w4, fo4 = optics.fast_water(Water(preset="moderate"), "article", 3.0, cal)
    assert fo4["irradiance"] == 1.0 and np.allclose(w4.B_inf, optics.get_preset("moderate").B_inf)
    w5, _ = optics.fast_water(Water(preset="jerlov_1C"), "article", 2.0)  # colour = physical veil x E_d
    assert np.allclose(w5.B_inf, 2.0 * optics.light_field_veil(optics.get_preset("jerlov_1C")))
    assert optics.fast_water(Water(preset="moderate", blur=True), "physical", 3.0)[1]["blur"]
    assert not np.any(optics.fast_water(Water(preset="clear"), "article", 3.0)[0].c)
    clear = optics.fast_water(Water(preset="clear"), "physical", 3.0)[0]  # physical clear: Jerlov I
    assert np.allclose(clear.c, optics.get_preset("jerlov_I").c)


def test_shipped_calibration_file_is_consistent():
    data = optics.load_calibration()
    if not data:
        pytest.skip("no calibration file (run dockbench calibrate-water)")
    for name, e in data["presets"].items():
        optics.get_preset(name)
        assert len(e["B_inf"]) == 3 and len(e["Kd"]) == 3
        assert e["residual"]["calibrated"]["mae"] <= e["residual"]["uncalibrated"]["mae"]


def test_pareto_plot(tmp_path):
    import pandas as pd

    df = pd.DataFrame(
        [
            {"setting": "reference s64", "condition": "mild", "ms_per_frame": 900.0, "mae": 0.0},
            {"setting": "fast s1", "condition": "mild", "ms_per_frame": 20.0, "mae": 0.01},
            {"setting": "fast s4", "condition": "mild", "ms_per_frame": 40.0, "mae": 0.005},
            {"setting": "fast s4", "condition": "clear", "ms_per_frame": 40.0, "mae": 0.001},
        ]
    )
    fidelity.pareto_plot(df, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_commands_are_click_commands_without_bpy():
    """In a fresh interpreter: another test of this session may have imported bpy already."""
    import subprocess
    from pathlib import Path

    code = (
        "import sys, click, cli\n"
        "assert isinstance(cli.main.commands['calibrate-water'], click.Command)\n"
        "assert isinstance(cli.main.commands['preview'], click.Command)\n"
        "assert isinstance(cli.bench.commands['fidelity'], click.Command)\n"
        "assert 'bpy' not in sys.modules, 'bpy imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[1])


@pytest.mark.blender
def test_calibration_and_preview_render_tiny(tmp_path):
    """End to end at 64x48: calibration improves the fast model; the preview sheet is whole."""
    data = fidelity.run_calibration(
        tmp_path / "work", tmp_path / "cal.json", 64, 48, 3, 8, conditions=("clear", "moderate"), echo=lambda m: None
    )
    key = optics.effective_preset(Water(preset="moderate"), "physical")  # its Jerlov type, as rendered
    e = json.loads((tmp_path / "cal.json").read_text())["presets"][key]
    assert e == data["presets"][key] and e["n_pixels"] > 200
    assert e["residual"]["calibrated"]["mae"] < e["residual"]["uncalibrated"]["mae"]
    import cv2

    from blendgen.tools.apps import preview

    p = preview.make_preview(tmp_path / "sheet.png", 48, 36, 1)
    img = cv2.imread(str(p))
    assert img.shape == (22 + 3 * 36, 9 * 48, 3)
