"""Instruction following: a policy that picks the named block follows every swap, one that ignores the
sentence follows none; the footprint test is the block's rotated square."""

import math

import cv2
import numpy as np
import pytest

from cliport.env import heightmap as hm
from cliport.errors import ConfigError
from cliport.evaluation.instruction_following import instruction_following, on_block, two_instructions_figure
from cliport.tasks.colors import COLORS

TASK = "put-one-block-in-bowl-seen-colors"


class ColourPicker:
    """Picks the centroid of the largest patch of block-high cells nearest in colour to the instruction's first
    colour word (``ignore_language``: always the first colour word of the scene's own instruction)."""

    name = "colour-picker"

    def __init__(self, ignore_language: bool = False) -> None:
        self.ignore_language = ignore_language
        self.first_instruction: str | None = None

    def similarity_heatmaps(self, obs, instruction):
        return {}

    def act(self, obs, instruction):
        if self.ignore_language:
            instruction = self.first_instruction
        colour = next(w for w in instruction.split() if w in COLORS)
        palette = np.asarray(list(COLORS.values()), np.float32)
        distance = np.linalg.norm(obs["color"].astype(np.float32)[..., None, :] - palette, axis=-1)
        nearest = np.asarray(list(COLORS))[distance.argmin(-1)]  # each cell's nearest named colour
        mask = (nearest == colour) & (obs["height"] > 0.03)
        _, labels, stats, centroids = cv2.connectedComponentsWithStats(mask.astype(np.uint8))
        largest = 1 + int(stats[1:, cv2.CC_STAT_AREA].argmax())  # shading specks elsewhere are smaller
        v, u = centroids[largest].round().astype(int)
        xyz = hm.pix_to_xyz((int(u), int(v)), obs["height"])
        identity = (0.0, 0.0, 0.0, 1.0)
        return {
            "pose0": (xyz, identity), "pose1": (xyz, identity), "pick_pix": (int(u), int(v)),
            "place_pix": (int(u), int(v)), "place_rot": 0.0,
            "pick_heatmap": mask.astype(np.float32), "place_heatmap": mask.astype(np.float32),
        }  # fmt: skip


def test_on_block_is_the_rotated_square_plus_the_margin():
    centre = np.array([0.5, 0.0])
    assert on_block(centre + [0.024, 0.0], centre, 0.0)  # 2 cm half-width + 5 mm
    assert not on_block(centre + [0.026, 0.0], centre, 0.0)
    assert not on_block(centre + [0.022, 0.022], centre, math.pi / 4)  # the corner direction, turned to an edge
    assert on_block(centre + [0.022, 0.022], centre, 0.0)


def test_a_policy_that_reads_the_colour_follows_every_swap_and_one_that_ignores_it_none():
    seeds = [10001, 10003, 10005]
    result = instruction_following(ColourPicker(), TASK, seeds, camera_scale=0.5)
    assert result["n"] == 2 * len(seeds) and result["rate"] == 1.0
    assert all(s["picked"] == s["named"] for s in result["swaps"])

    stubborn = ColourPicker(ignore_language=True)
    seen = []

    def remember_own_instruction(obs, act, instruction):
        seen.append(instruction)

    from cliport.evaluation.instruction_following import scene_instruction

    rates = []
    for seed in seeds:
        stubborn.first_instruction = scene_instruction(TASK, seed, camera_scale=0.5)
        rates.append(instruction_following(stubborn, TASK, [seed], 0.5, on_swap=remember_own_instruction)["rate"])
    assert rates == [0.0] * len(seeds) and len(seen) == 2 * len(seeds)


def test_tasks_that_do_not_name_their_blocks_are_refused():
    with pytest.raises(ConfigError, match="place-red-in-green"):
        instruction_following(ColourPicker(), "place-red-in-green", [10001])


def test_the_figure_shows_one_scene_under_two_instructions(tmp_path):
    from PIL import Image

    path = tmp_path / "two.png"
    own, other = two_instructions_figure(ColourPicker(), TASK, 10001, str(path), camera_scale=0.5)
    assert own != other and own.split()[2] != other.split()[2] and own.split()[-2] != other.split()[-2]
    image = Image.open(path)
    assert image.size[1] > 2 * 320  # two rows of 320-pixel panels (scaled 2x) with their captions
