import pickle
import sys
import types
from collections import OrderedDict

import pytest
import torch

from cliport.utils.safe_pickle import (
    InertObject,
    UnreadablePickleError,
    UnsafePickleError,
    load_torch_checkpoint,
)


class _Evaluates:
    def __reduce__(self):
        return (eval, ("__import__('os').system('true')",))


@pytest.fixture
def fake_omegaconf(monkeypatch):
    """A class pickled under omegaconf's name, as a Lightning checkpoint's hyper-parameters are."""
    module = types.ModuleType("omegaconf.dictconfig")

    class DictConfig(dict):
        def __init__(self, content):
            super().__init__(content)
            self.flags = {"readonly": False}

    DictConfig.__module__, DictConfig.__qualname__ = "omegaconf.dictconfig", "DictConfig"
    module.DictConfig = DictConfig
    monkeypatch.setitem(sys.modules, "omegaconf", types.ModuleType("omegaconf"))
    monkeypatch.setitem(sys.modules, "omegaconf.dictconfig", module)
    return DictConfig


def test_a_lightning_checkpoint_loads_with_data_classes_inert(tmp_path, fake_omegaconf) -> None:
    state = OrderedDict(w=torch.randn(3, 4), h=torch.randn(5).half(), n=torch.tensor(7))
    state["view"] = state["w"][1:, ::2]  # shares its storage
    ckpt = {"state_dict": state, "global_step": 9, "hyper_parameters": fake_omegaconf({"train": {"n_rotations": 36}})}
    path = tmp_path / "a.ckpt"
    torch.save(ckpt, path)
    out = load_torch_checkpoint(str(path))
    assert out["global_step"] == 9
    for key, value in state.items():
        assert torch.equal(out["state_dict"][key], value) and out["state_dict"][key].dtype == value.dtype
    hp = out["hyper_parameters"]
    assert isinstance(hp, InertObject) and hp.global_name == "omegaconf.dictconfig.DictConfig"
    assert hp.entries == {"train": {"n_rotations": 36}}  # the data is kept, no omegaconf code ran


@pytest.mark.parametrize("payload", ["system", "eval"])
def test_a_checkpoint_that_carries_code_is_refused_and_nothing_runs(tmp_path, payload, runs_code) -> None:
    marker = tmp_path / "ran"
    evil = runs_code(f"touch {marker}") if payload == "system" else _Evaluates()
    path = tmp_path / "evil.ckpt"
    torch.save({"state_dict": {"w": torch.zeros(2)}, "callbacks": evil}, path)
    with pytest.raises(UnsafePickleError) as err:
        load_torch_checkpoint(str(path))
    message = str(err.value)
    assert str(path) in message and ("posix.system" in message or "builtins.eval" in message)
    assert "\n" not in message
    assert not marker.exists()


def test_truncated_and_foreign_files_are_one_line_errors(tmp_path) -> None:
    path = tmp_path / "ok.ckpt"
    torch.save({"state_dict": {"w": torch.randn(1000)}}, path)
    data = path.read_bytes()
    cut = tmp_path / "cut.ckpt"
    cut.write_bytes(data[: len(data) // 2])
    plain = tmp_path / "plain.pkl"
    plain.write_bytes(pickle.dumps({"w": 1}))
    for bad, phrase in ((cut, "not a zip-format"), (plain, "not a zip-format"), (tmp_path / "none", "does not exist")):
        with pytest.raises(UnreadablePickleError, match=phrase) as err:
            load_torch_checkpoint(str(bad))
        assert "\n" not in str(err.value)
