"""cliport's own small open_clip configs (the semantic encoders ``cliport-pretrain`` trains on a CPU) are names like
open_clip's, and R3M's published ResNet-50 checkpoint loads as an RN50 trunk."""

from __future__ import annotations

import json

import pytest
import torch

from cliport.models.encoders import clip_registry
from cliport.models.encoders.clip_encoder import load_clip
from cliport.models.encoders.clip_weights import CLIPWeightsUnavailable, published_weights_available
from cliport.models.encoders.rn50_trunk import ResNet50Trunk, RN50WeightsUnavailable, _resnet50, build_rn50_trunk


@pytest.mark.parametrize("name", ["cliport-RN-tiny", "cliport-RN-small"])
def test_cliports_configs_are_open_clip_names(name: str) -> None:
    on_disk = json.loads((clip_registry.CLIPORT_CONFIG_DIR / f"{name}.json").read_text())
    clip_registry.check_model_name(name)
    assert clip_registry.model_config(name) == on_disk
    open_clip = clip_registry.import_open_clip()
    assert name in open_clip.list_models() and open_clip.get_model_config(name) == on_disk
    assert clip_registry.pretrained_tags(name) == []
    assert not published_weights_available(model_name=name)  # no published weights: never "openai"


def test_the_tiny_encoder_is_a_semantic_encoder() -> None:
    """Random weights of cliport-RN-tiny: five trunk levels at the five strides with its widths, 256-wide sentences
    of up to 24 tokens; "openai" is refused in one line (no such weights)."""
    encoder = load_clip("random", "cliport-RN-tiny")
    assert encoder.trunk_channels == (16, 64, 128, 256, 512) and encoder.sentence_dim == 256
    assert encoder.context_length == 24
    levels = encoder.image_features(torch.rand(1, 3, 64, 32))
    assert [tuple(f.shape[1:]) for f in levels] == [(16, 16, 8), (64, 16, 8), (128, 8, 4), (256, 4, 2), (512, 2, 1)]
    assert encoder.sentence_features(["put the pink block in the white bowl"]).shape == (1, 256)
    with pytest.raises(CLIPWeightsUnavailable, match="no pretrained tags"):
        load_clip("openai", "cliport-RN-tiny")


def test_r3m_checkpoint_loads_as_the_rn50_trunk(tmp_path) -> None:
    """A file in R3M's format (``torch.save({"r3m": state})`` of its DataParallel model: ``module.convnet.*`` is a
    torchvision resnet50 without fc, ``module.lang_enc.*`` / ``module.lang_rew.*`` its language head) loads as
    ``--rn50-weights FILE``: the convnet's tensors, exactly; the language head is left out."""
    gen = torch.Generator().manual_seed(5)
    convnet = {
        k: (v + torch.randn(v.shape, generator=gen) if v.is_floating_point() else v).contiguous()
        for k, v in ResNet50Trunk(_resnet50()).state_dict().items()
    }
    state = {f"module.convnet.{k}": v for k, v in convnet.items()}
    state["module.lang_rew.pred.0.weight"] = torch.zeros(4, 4)
    state["module.lang_enc.modelm.weight"] = torch.zeros(2)
    path = tmp_path / "model.pt"
    torch.save({"r3m": state, "global_step": 5}, path)
    trunk = build_rn50_trunk(str(path))
    assert all(torch.equal(trunk.state_dict()[k], v) for k, v in convnet.items())
    broken = {k: v for k, v in state.items() if not k.endswith("layer4.2.conv3.weight")}
    torch.save({"r3m": broken}, path)
    with pytest.raises(RN50WeightsUnavailable, match="layer4.2.conv3.weight"):
        build_rn50_trunk(str(path))
