"""Which tasks need place rotations: each task's declaration agrees with what its goals check and what its
expert does, and cliport-train trains the others with one rotation by default."""

import pytest

from cliport import tasks
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import quat_to_yaw


def _goals_check_yaw(task) -> bool:
    return any(step.rotations and any(sym > 0 for sym in step.symmetries) for step in task.goals)


@pytest.mark.parametrize("name", tasks.names())
def test_declaration_matches_the_goals_and_the_expert(name: str) -> None:
    declared = tasks.make(name).place_yaw_informative
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=tasks.make(name, "train")) as env:
        env.reset(seed=0)
        assert _goals_check_yaw(env.task) == declared
        if not declared and not any(step.rotations for step in env.task.goals):
            action = env.task.oracle_act()  # placed without turning: the label is always bin 0
            assert abs(quat_to_yaw(action["pose1"][1]) - quat_to_yaw(action["pose0"][1])) < 1e-9


def test_groups_need_rotations_when_any_member_does() -> None:
    assert not tasks.place_yaw_informative("place-red-in-green")
    assert tasks.place_yaw_informative("block-insertion")
    assert tasks.place_yaw_informative("multi-language-conditioned")


def test_cliport_train_defaults_to_one_rotation_where_the_yaw_carries_nothing(capsys) -> None:
    from cliport.cli.train import _parser, config_from_args

    parser, dests = _parser()

    def config(*argv: str):
        return config_from_args(parser.parse_args(["--agent", "transporter_only", *argv]), dests)

    assert config("--task", "place-red-in-green").agent_config.n_rotations == 1
    assert "carries no information" in capsys.readouterr().err
    assert config("--task", "place-red-in-green", "--n-rotations", "36").agent_config.n_rotations == 36
    assert config("--task", "block-insertion").agent_config.n_rotations == 36
    assert capsys.readouterr().err == ""
