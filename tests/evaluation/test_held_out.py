"""Held-out checks: every instruction of a few validation scenes, scored from one action each."""

from __future__ import annotations

import numpy as np
import pytest

from cliport.data.seeds import episode_seeds
from cliport.evaluation.held_out import HeldOutCheck, record_scenes, score_scenes

TASK = "put-one-block-in-bowl-seen-colors"


@pytest.fixture(scope="module")
def scenes():
    return record_scenes(TASK, 2, camera_scale=0.5)


class Pointer:
    """Acts on a recorded scene by pointing at the named block and at a bowl (``wrong_bowl``: the other one)."""

    def __init__(self, scenes, wrong_bowl: bool = False) -> None:
        self.scenes, self.wrong_bowl = scenes, wrong_bowl

    def act_batch(self, observations, texts):
        scene = next(s for s in self.scenes if s.color is observations[0]["color"])
        acts = []
        for text in texts:
            _, block, bowl = next(named for named in scene.instructions if named[0] == text)
            if self.wrong_bowl:
                bowl = next(other for other in scene.bowls if other != bowl)
            (bx, by), _ = scene.blocks[block]
            px, py = scene.bowls[bowl]
            identity = (0.0, 0.0, 0.0, 1.0)
            acts.append({"pose0": ((bx, by, 0.02), identity), "pose1": ((px, py, 0.02), identity), "place_rot": 0.0})
        return acts


def test_scenes_are_validation_scenes_with_every_instruction(scenes) -> None:
    assert [scene.seed for scene in scenes] == list(episode_seeds("val", 2))
    assert not set(episode_seeds("val", 2)) & set(episode_seeds("test", 100))
    for scene in scenes:
        assert len(scene.blocks) == 3 and len(scene.bowls) == 2 and len(scene.instructions) == 6
        assert len({text for text, _, _ in scene.instructions}) == 6
        assert scene.color.shape[:2] == scene.height.shape


def test_pointing_at_the_named_block_and_bowl_solves_every_instruction(scenes) -> None:
    assert score_scenes(Pointer(scenes), scenes) == {"n": 12, "picks": 12, "places": 12, "solved": 12, "score": 1.0}


def test_the_other_bowl_gets_the_picks_but_no_place(scenes) -> None:
    result = score_scenes(Pointer(scenes, wrong_bowl=True), scenes)
    assert (result["picks"], result["places"], result["solved"], result["score"]) == (12, 0, 0, 0.0)


def test_a_pick_beside_every_block_is_wrong(scenes) -> None:
    class Beside(Pointer):
        def act_batch(self, observations, texts):
            acts = super().act_batch(observations, texts)
            for act in acts:
                (x, y, z), quat = act["pose0"]
                act["pose0"] = ((x + 0.06, y, z), quat)  # 6 cm off: beyond a 4 cm block and the cup's rim
            return acts

    result = score_scenes(Beside(scenes), scenes)
    assert result["picks"] == 0 and result["solved"] == 0


def test_checks_are_due_on_their_schedule(scenes) -> None:
    check = HeldOutCheck(scenes, every=300, start=300)
    assert [step for step in range(0, 1300, 100) if check.due(step)] == [300, 600, 900, 1200]
    assert check.describe()["samples"] == 12 and check.describe()["scenes"] == [s.seed for s in scenes]
    with pytest.raises(ValueError, match="every >= 1"):
        HeldOutCheck(scenes, every=0)
    assert np.isfinite(check.check(300, Pointer(scenes))["score"])
