"""Action panels: the observation, the pick and place heatmaps, and any similarity maps side by side."""

from __future__ import annotations

import numpy as np

from cliport.evaluation.visualize import action_panel, heatmap_overlay

H, W = 320, 160


def _act() -> dict:
    pick = np.zeros((H, W), np.float32)
    pick[100, 50] = 1.0
    place = np.zeros((H, W), np.float32)
    place[200, 120] = 1.0
    return {
        "pick_heatmap": pick,
        "place_heatmap": place,
        "pick_pix": (100, 50),
        "place_pix": (200, 120),
        "place_rot": 0.0,
    }


def test_heatmap_overlay_paints_the_peak_red_and_the_rest_blue() -> None:
    color = np.full((H, W, 3), 128, np.uint8)
    heat = np.zeros((H, W), np.float32)
    heat[10, 20] = 2.0
    out = heatmap_overlay(color, heat, alpha=1.0)
    assert out[10, 20, 0] > 100 and out[10, 20, 2] < 50  # jet's top is red
    assert out[0, 0, 2] > 100 and out[0, 0, 0] < 50  # its bottom blue


def test_action_panel_adds_one_labelled_panel_per_similarity_map() -> None:
    obs = {"color": np.full((H, W, 3), 90, np.uint8)}
    plain = action_panel(obs, _act(), "put the red block in the green bowl", scale=1)
    assert plain.shape == (28 + H, 3 * W, 3)
    ramp = np.tile(np.linspace(-0.2, 0.3, W, dtype=np.float32), (H, 1))  # cosines, highest on the right
    maps = {"the red block": ramp, "the green bowl": -ramp}
    panel = action_panel(obs, _act(), "put the red block in the green bowl", scale=1, similarity=maps)
    assert panel.shape == (28 + H, 5 * W, 3)
    np.testing.assert_array_equal(panel[:, : 3 * W], plain)
    red_block, green_bowl = panel[28:, 3 * W : 4 * W], panel[28:, 4 * W :]
    row = H - 5  # below the label
    assert red_block[row, -1, 0] > red_block[row, -1, 2] and red_block[row, 0, 2] > red_block[row, 0, 0]
    assert green_bowl[row, 0, 0] > green_bowl[row, 0, 2]  # negated: its peak on the left
    assert (red_block[:20] != heatmap_overlay(obs["color"], (ramp + 0.2) / 0.5)[:20]).any()  # the label
