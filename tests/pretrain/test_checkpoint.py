"""The pretrained encoder round-trips through ``--clip-weights PATH``: written by cliport-pretrain, loaded by the path
every CLIP weights file takes (and by open_clip's own ``local-dir:``), frozen in an agent whose checkpoints record
the file and the architecture, and reloaded from them with identical tensors."""

from __future__ import annotations

import os

import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent
from cliport.models.encoders.clip_encoder import load_clip
from cliport.models.encoders.clip_registry import import_open_clip
from cliport.models.encoders.clip_weights import CLIPWeightsUnavailable
from cliport.pretrain.checkpoint import CONFIG_FILE, WEIGHTS_FILE, read_open_clip_metadata
from cliport.pretrain.trainer import pretrain
from cliport.utils.files import load_safetensors


@pytest.fixture(scope="module")
def pretrained(tiny_cache: str, tmp_path_factory: pytest.TempPathFactory) -> str:
    from cliport.pretrain.config import load_config

    out = str(tmp_path_factory.mktemp("pretrained"))
    settings = {"out_dir": out, "cache_dir": tiny_cache, "train_scenes": 6, "probe_scenes": 3, "renderer": "cpu",
                "steps": 3, "batch_size": 16, "warmup_steps": 1, "log_every": 1, "save_every": 3}  # fmt: skip
    record = pretrain(load_config(settings), progress=False, probe=False)
    assert record["weights"] == os.path.join(out, WEIGHTS_FILE)
    return record["weights"]


def test_weights_load_through_clip_weights_unchanged(pretrained: str) -> None:
    written, _ = load_safetensors(pretrained)
    encoder = load_clip(pretrained, "cliport-RN-tiny")
    loaded = encoder.model.state_dict()
    assert set(loaded) == set(written)
    assert all(torch.equal(loaded[k], written[k]) for k in written)
    assert encoder.sources() == {"clip_weights": pretrained}
    metadata = read_open_clip_metadata(pretrained)
    assert metadata["open_clip_model"] == "cliport-RN-tiny" and metadata["source"] == "cliport-pretrain"
    assert metadata["steps"] == "3"


def test_open_clip_reads_the_folder_as_its_own(pretrained: str) -> None:
    folder = os.path.dirname(pretrained)
    assert os.path.isfile(os.path.join(folder, CONFIG_FILE))
    open_clip = import_open_clip()
    model = open_clip.create_model(f"local-dir:{folder}")
    written, _ = load_safetensors(pretrained)
    assert all(torch.equal(model.state_dict()[k], written[k]) for k in written)


def test_the_agent_freezes_it_and_its_checkpoint_records_it(pretrained: str, tmp_path) -> None:
    config = {"clip_weights": pretrained, "semantic_encoder": "cliport-RN-tiny", "width": 0.0625, "n_rotations": 1,
              "map_scale": 0.5}  # fmt: skip
    agent = make_agent("two_stream", config)
    written, _ = load_safetensors(pretrained)
    assert all(torch.equal(agent.encoder.model.state_dict()[k], written[k]) for k in written)
    assert agent.encoder.trunk_channels == (16, 64, 128, 256, 512) and agent.encoder.sentence_dim == 256
    path = str(tmp_path / "agent.pt")
    agent.save_checkpoint(path)
    payload = torch.load(path, weights_only=True)
    assert payload["clip_weights"] == pretrained and payload["config"]["semantic_encoder"] == "cliport-RN-tiny"
    assert not any("encoder" in k and "model" in k for k in payload["state_dict"])  # frozen weights never saved
    again = PickPlaceAgent.from_pretrained(path)
    assert all(torch.equal(again.encoder.model.state_dict()[k], written[k]) for k in written)
    other = PickPlaceAgent.from_pretrained(path, weights={"clip_weights": "random"})  # another source, same nets
    assert other.clip_source() == "random" and other.config.clip_weights == "random"
    assert not all(torch.equal(other.encoder.model.state_dict()[k], written[k]) for k in written)
    trained = agent.trainable_state_dict()
    assert all(torch.equal(v, trained[k]) for k, v in other.trainable_state_dict().items())


def test_the_wrong_architecture_is_one_line(pretrained: str) -> None:
    with pytest.raises(CLIPWeightsUnavailable) as caught:
        load_clip(pretrained, "cliport-RN-small")
    message = str(caught.value)
    assert "\n" not in message and "cliport-RN-tiny" in message and pretrained in message
