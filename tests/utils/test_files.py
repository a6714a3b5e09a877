import os

import pytest
import torch

from cliport.errors import CheckpointError
from cliport.utils.files import load_torch, read_json, save_torch, write_json


def test_json_and_torch_round_trip_leave_no_temp_files(tmp_path):
    write_json(tmp_path / "a" / "x.json", {"k": [1, 2]})
    save_torch({"w": torch.ones(2)}, tmp_path / "a" / "x.pt")
    assert read_json(tmp_path / "a" / "x.json") == {"k": [1, 2]}
    assert torch.equal(load_torch(tmp_path / "a" / "x.pt")["w"], torch.ones(2))
    assert sorted(os.listdir(tmp_path / "a")) == ["x.json", "x.pt"]


def test_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "x.json"
    write_json(path, {"old": 1})
    with pytest.raises(TypeError):
        write_json(path, {"new": object()})
    assert read_json(path) == {"old": 1} and os.listdir(tmp_path) == ["x.json"]


@pytest.mark.parametrize("damage", ["truncate", "garbage", "missing"])
def test_unreadable_checkpoints_name_the_file(tmp_path, damage):
    path = tmp_path / "ckpt.pt"
    save_torch({"w": torch.randn(100, 100)}, path)
    if damage == "truncate":
        with open(path, "r+b") as f:
            f.truncate(os.path.getsize(path) // 2)
    elif damage == "garbage":
        path.write_bytes(os.urandom(2000))
    else:
        path.unlink()
    with pytest.raises(CheckpointError) as err:
        load_torch(path)
    message = str(err.value)
    assert str(path) in message and "weights_only=False" not in message and "\n" not in message


def test_read_json_maps_a_missing_or_broken_file_to_the_callers_error(tmp_path):
    from cliport.errors import ConfigError

    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(FileNotFoundError):
        read_json(tmp_path / "nope.json")
    with pytest.raises(ConfigError, match="^cameras file not found: x$"):
        read_json(tmp_path / "nope.json", ConfigError, "cameras file not found: x")
    with pytest.raises(ConfigError, match=f"^{tmp_path / 'nope.json'} not found$"):
        read_json(tmp_path / "nope.json", ConfigError)
    with pytest.raises(ConfigError, match=f"^{broken} is not valid JSON: Expecting property name"):
        read_json(broken, ConfigError)
