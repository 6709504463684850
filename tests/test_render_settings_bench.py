"""bench render-settings: its image deltas and localization table are right on known inputs."""

import math

import numpy as np
import pandas as pd
import pytest

from blendgen.tools.bench import render_settings as rs


def test_identical_images_give_zero_deltas():
    img = np.random.default_rng(0).integers(0, 256, (12, 16, 3), dtype=np.uint8)
    mask = np.zeros((12, 16), bool)
    mask[2:6, 3:9] = True
    d = rs.frame_image_deltas(img, img.copy(), mask)
    assert d["marker_max_dn"] == 0 and d["marker_mean_dn"] == 0 and math.isinf(d["marker_psnr_db"])
    assert d["marker_px"] == 24 and d["off_marker_mean_dn"] == 0


def test_known_difference_on_and_off_the_markers():
    a = np.full((10, 10, 3), 255, np.uint8)
    b = a.copy()
    b[0, 0] = 0  # one marker pixel black instead of white: linear error 1 on 3 of 12 values
    b[9, 9] = 254  # one off-marker pixel 1 DN darker
    mask = np.zeros((10, 10), bool)
    mask[:2, :2] = True
    d = rs.frame_image_deltas(a, b, mask)
    assert d["marker_max_dn"] == 255 and d["marker_mean_dn"] == pytest.approx(255 / 4)
    assert d["marker_psnr_db"] == pytest.approx(10 * math.log10(4.0))  # mse = 3/12
    assert d["off_marker_mean_dn"] == pytest.approx(3 / (96 * 3))


def test_localization_table_deltas_and_bins():
    def frames(success, e_rel):
        return pd.DataFrame(
            {"localizer": ["qr"] * 4, "d_true": [0.5, 0.7, 3.0, 12.0], "success": success, "e_rel": e_rel}
        )

    base = frames([True, False, True, True], [0.01, np.nan, 0.02, 0.5])
    var = frames([True, True, False, True], [0.03, 0.01, np.nan, 0.5])
    t = rs.localization_table(base, var).set_index("range_m")
    assert t.loc["all", "frames_base"] == 3  # d_true > 10 m is outside the window
    assert t.loc["all", "dP_succ"] == pytest.approx(0.0)
    assert t.loc["[0.0, 1.0)", "P_succ_base"] == 0.5 and t.loc["[0.0, 1.0)", "P_succ_variant"] == 1.0
    assert t.loc["[0.0, 1.0)", "dE_rel_median"] == pytest.approx(0.02 - 0.01)
