import pytest

from cliport.agents.config import CLIPConfig
from cliport.errors import ConfigError, UnknownNameError
from cliport.train.config import TrainConfig
from cliport.train.trainer import checkpoint_schedule


def test_build_nests_the_agent_and_env_defaults():
    config = TrainConfig.build({"task": "block-insertion", "agent_config": {"width": 0.5}})
    assert config.agent == "two_stream" and isinstance(config.agent_config, CLIPConfig)
    assert config.agent_config.width == 0.5 and config.agent_config.n_rotations == 36
    assert config.env.camera_scale == 1.0 and config.env.renderer == "auto"
    assert config.resolved_run_dir() == "runs/block-insertion-two_stream-n100-s0"
    again = TrainConfig.build(base=config.to_dict())
    assert again == config


@pytest.mark.parametrize(
    "overrides, error, message",
    [
        ({"agent": "cliport9"}, UnknownNameError, "unknown agent 'cliport9'"),
        ({"agent": "transporter_only", "agent_config": {"clip_weights": "x"}}, ConfigError,
         "agent transporter_only has no setting(s) clip_weights"),
        ({"batch_size": 0}, ConfigError, "batch_size must be >= 1, got 0"),
        ({"n_stpes": 3}, ConfigError, "unknown TrainConfig key(s) 'n_stpes' (did you mean 'n_steps'?)"),
        ({"amp": "fp8"}, ConfigError, "amp must be auto, bf16 or none"),
        ({"env": {"camera_scale": -1.0}}, ConfigError, "camera_scale must be > 0"),
        ({"agent_config": {"width": -1}}, ConfigError, "width must be > 0"),
        ({"pair_contrasts": True}, ConfigError, "pair_contrasts pairs the instructions of a scene: it needs every"),
    ],
)  # fmt: skip
def test_bad_settings_are_named(overrides, error, message):
    with pytest.raises(error) as err:
        TrainConfig.build({"task": "block-insertion", **overrides})
    assert message in str(err.value)


def test_a_config_saved_before_nesting_still_loads():
    old = {
        "agent": "two_stream", "n_demos": 2, "n_steps": 10, "batch_size": 2, "data_dir": "d", "device": "cpu",
        "seed": 0, "num_workers": 0, "amp": "auto", "checkpoint_steps": [5], "checkpoint_every": 0,
        "save_last_every": 500, "log_every": 5, "val_episodes": 1, "camera_scale": 0.5, "task": "block-insertion",
        "run_dir": None, "lr": 0.001, "clip_weights": "random", "agent_overrides": {"width": 0.125},
    }  # fmt: skip
    config = TrainConfig.from_saved(old)
    assert config.agent_config.width == 0.125 and config.agent_config.lr == 0.001
    assert config.agent_config.clip_weights == "random" and config.env.camera_scale == 0.5
    assert config.run_dir == ""


def test_checkpoint_schedule():
    config = TrainConfig.build({"task": "t", "n_steps": 45000})
    assert checkpoint_schedule(config) == [1000, 2000, 5000, 10000, 20000, 40000, 45000]


def test_user_errors_raised_in_loader_workers_come_back_as_one_line():
    import torch
    from torch.utils.data import DataLoader, Dataset

    from cliport.data.episode_io import EpisodeFileError
    from cliport.train.step_loop import _batches, _next_batch

    class Broken(Dataset):
        def __len__(self) -> int:
            return 4

        def __getitem__(self, i: int) -> torch.Tensor:
            raise EpisodeFileError("corrupt episode file /d/000002.npz: the 'color' array is damaged")

    with pytest.raises(EpisodeFileError) as err:
        _next_batch(_batches(DataLoader(Broken(), batch_size=2, num_workers=1)))
    assert str(err.value) == "corrupt episode file /d/000002.npz: the 'color' array is damaged"


def test_load_run_config_reads_a_runs_config_or_says_why_not(tmp_path):
    from cliport.errors import RunDirError
    from cliport.train.config import load_run_config
    from cliport.utils.files import write_json

    with pytest.raises(RunDirError, match="run folder not found"):
        load_run_config(str(tmp_path / "nope"))
    with pytest.raises(RunDirError, match="is not a training run \\(no config.json\\)"):
        load_run_config(str(tmp_path))
    config = TrainConfig.build({"task": "block-insertion", "agent": "transporter_only"})
    write_json(tmp_path / "config.json", config.to_dict())
    assert load_run_config(str(tmp_path)) == config


def test_agent_settings_the_agent_lacks_are_named_once_with_its_settings():
    with pytest.raises(ConfigError) as err:
        TrainConfig.build({"task": "block-insertion", "agent": "transporter_only", "agent_config": {"clip_weight": 1}})
    assert str(err.value) == (
        "agent transporter_only has no setting(s) clip_weight; "
        "its settings: crop_size, lr, map_scale, n_rotations, width"
    )
