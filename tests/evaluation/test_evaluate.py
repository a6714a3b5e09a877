import pytest

from cliport.evaluation.evaluate import confidence_interval, success_interval


def test_wilson_interval_known_values():
    assert success_interval(100, 100) == pytest.approx((96.30, 100.0), abs=0.01)
    assert success_interval(0, 10) == pytest.approx((0.0, 27.75), abs=0.01)
    low, high = success_interval(50, 100)
    assert low == pytest.approx(40.38, abs=0.01) and high == pytest.approx(59.62, abs=0.01)


def test_score_interval_is_clipped_to_the_score_range():
    low, high = confidence_interval([100.0] * 9 + [0.0])
    assert high == 100.0 and 0.0 < low < 90.0
    assert confidence_interval([100.0] * 5) == (100.0, 100.0)


def test_an_agents_episode_records_its_instruction():
    from cliport.evaluation.evaluate import evaluate
    from cliport.evaluation.instruction_following import scene_instruction

    class Still:
        """Picks and places at the workspace's centre: the episode ends unsolved, its instruction read."""

        def act_batch(self, observations, instructions):
            pose = ((0.5, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
            return [{"pose0": pose, "pose1": pose} for _ in observations]

    task = "put-block-in-bowl-seen-colors"
    result = evaluate(Still(), task, "test", 1, camera_scale=0.5, progress=False, workers=1, step_timeout=None)
    (episode,) = result["episodes"]
    assert episode["instruction"] == scene_instruction(task, episode["seed"], camera_scale=0.5)
    assert episode["instruction"].startswith("put the ")
