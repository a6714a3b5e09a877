"""Semantic encoders other than the default RN50: open_clip models chosen by name (random weights here)."""

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from cliport.errors import UserError
from cliport.models.encoders import clip_weights
from cliport.models.encoders.clip_encoder import FrozenCLIP, load_clip
from cliport.models.encoders.clip_registry import UnknownEncoderError, UnsupportedEncoderError
from cliport.models.encoders.clip_vit import vit_block_indices
from cliport.models.encoders.clip_weights import CLIPWeightsUnavailable, build_clip_model
from cliport.models.semantic import SemanticNet
from cliport.models.two_stream import TwoStreamNet

# Smallest open_clip model with a text tower and open_clip's own tokenizer (~42M parameters).
SMALL_MODEL = "ViT-S-32-alt"
EXPECTED = {
    "RN101-quickgelu": ((64, 256, 512, 1024, 2048), 512),
    "ViT-B-16": ((768, 768, 768, 768, 768), 512),
}


@pytest.fixture(scope="module")
def rn101() -> FrozenCLIP:
    return load_clip("random", "RN101-quickgelu")


@pytest.fixture(scope="module")
def vit() -> FrozenCLIP:
    return load_clip("random", "ViT-B-16")


@pytest.fixture(scope="module", params=["rn101", "vit"])
def encoder(request: pytest.FixtureRequest) -> FrozenCLIP:
    return request.getfixturevalue(request.param)


def _images(seed: int, h: int, w: int, n: int = 2) -> torch.Tensor:
    return torch.rand(n, 3, h, w, generator=torch.Generator().manual_seed(seed))


def test_widths_are_read_from_the_model(encoder: FrozenCLIP) -> None:
    assert (encoder.trunk_channels, encoder.sentence_dim) == EXPECTED[encoder.model_name]
    assert encoder.context_length == 77


def test_image_features_have_five_levels_at_the_trunk_strides(encoder: FrozenCLIP) -> None:
    feats = encoder.image_features(_images(0, 64, 96))
    sizes = [(16, 24), (16, 24), (8, 12), (4, 6), (2, 3)]
    assert [tuple(f.shape) for f in feats] == [(2, c, *hw) for c, hw in zip(encoder.trunk_channels, sizes, strict=True)]
    assert all(f.dtype == torch.float32 and not f.requires_grad and torch.isfinite(f).all() for f in feats)


def test_sentence_features_differ_between_sentences(encoder: FrozenCLIP) -> None:
    feats = encoder.sentence_features(["pack the box", "push the pile"])
    assert feats.shape == (2, encoder.sentence_dim)
    assert not torch.allclose(feats[0], feats[1])


def test_frozen_stays_in_eval_mode_without_grads(encoder: FrozenCLIP) -> None:
    encoder.train()
    assert not encoder.training and not any(m.training for m in encoder.modules())
    assert not any(p.requires_grad for p in encoder.parameters())


def test_vit_uses_blocks_3_6_9_12(vit: FrozenCLIP) -> None:
    assert vit.vit_blocks == (2, 5, 8, 11)
    assert vit_block_indices(24) == (5, 11, 17, 23)


def test_vit_features_follow_the_image(vit: FrozenCLIP) -> None:
    a = vit.image_features(_images(1, 64, 64))
    b = vit.image_features(_images(2, 64, 64))
    assert [tuple(f.shape) for f in a] == [(2, 768, 16, 16)] * 2 + [(2, 768, 8, 8), (2, 768, 4, 4), (2, 768, 2, 2)]
    assert all(not torch.allclose(x, y) for x, y in zip(a, b, strict=True))
    # Two different images in one batch give different features too (no cross-talk through the resizing).
    assert not torch.allclose(a[4][0], a[4][1])


def test_vit_runs_at_320_without_touching_its_position_embeddings(vit: FrozenCLIP) -> None:
    before = vit.model.visual.positional_embedding.clone()
    feats = vit.image_features(_images(3, 320, 320, n=1))
    assert [tuple(f.shape[-2:]) for f in feats] == [(80, 80), (80, 80), (40, 40), (20, 20), (10, 10)]
    assert torch.equal(vit.model.visual.positional_embedding, before)


def test_vit_levels_at_the_native_size_are_open_clips_own_block_outputs(vit: FrozenCLIP) -> None:
    """At 224 x 224 the position embeddings are not resized: the stride-16 level is block 9's token grid."""
    rgb = _images(4, 224, 224, n=1)
    ours = vit.image_features(rgb)
    x = (rgb - vit.mean) / vit.std
    with torch.no_grad():
        theirs = vit.model.visual.forward_intermediates(x, indices=[2, 5, 8, 11], intermediates_only=True)
    blocks = theirs["image_intermediates"]
    assert torch.allclose(ours[3], blocks[2], atol=1e-5)
    assert torch.allclose(ours[4], torch.nn.functional.avg_pool2d(blocks[3], 2), atol=1e-5)
    assert torch.equal(ours[0], ours[1])  # the stem is block 3 at stride 4


@pytest.mark.parametrize("net", ["semantic", "two-stream"])
def test_decoders_train_on_other_encoder_widths(encoder: FrozenCLIP, net: str) -> None:
    torch.manual_seed(0)
    model = (
        SemanticNet(encoder, 3, width=0.125)
        if net == "semantic"
        else TwoStreamNet(encoder, 3, width=0.125, conv_fusion=True)
    )
    x = torch.cat([_images(5, 64, 64), torch.rand(2, 3, 64, 64) * 0.1], dim=1)
    out = model(x, encoder.sentence_features(["pack the box", "push the pile"]))
    assert out.shape == (2, 3, 64, 64)
    out.square().mean().backward()
    trainable = [p for n, p in model.named_parameters() if not n.startswith("encoder.")]
    assert trainable and all(p.grad is not None for p in trainable)
    assert all(p.grad is None for p in encoder.parameters())


def test_unknown_name_is_one_line_with_the_closest_names() -> None:
    start = time.monotonic()
    with pytest.raises(UnknownEncoderError) as err:
        load_clip("random", "ViT-B-61")
    assert time.monotonic() - start < 1
    message = str(err.value)
    assert isinstance(err.value, UserError) and isinstance(err.value, ValueError)
    assert "'ViT-B-61'" in message and "ViT-B-16" in message and "\n" not in message, message


def test_timm_image_towers_are_refused_before_anything_is_fetched() -> None:
    start = time.monotonic()
    with pytest.raises(UnsupportedEncoderError) as err:
        build_clip_model("webli", "ViT-B-16-SigLIP")
    assert time.monotonic() - start < 1
    assert "timm" in str(err.value) and "\n" not in str(err.value)


def test_state_dict_file_of_another_model_round_trips(tmp_path: Path) -> None:
    model = build_clip_model("random", SMALL_MODEL)
    gen = torch.Generator().manual_seed(123)  # differ from the seeded random init: a fallback would show
    state = {
        k: (v + 0.01 * torch.randn(v.shape, generator=gen) if v.is_floating_point() else v).contiguous()
        for k, v in model.state_dict().items()
    }
    path = tmp_path / "small.safetensors"
    save_file(state, str(path))
    loaded = load_clip(str(path), SMALL_MODEL)
    assert loaded.model_name == SMALL_MODEL and loaded.sources() == {"clip_weights": str(path)}
    got = loaded.model.state_dict()
    assert got.keys() == state.keys()
    assert all(torch.equal(got[k], v) for k, v in state.items())
    # The same file read as another architecture: one line naming that model.
    with pytest.raises(CLIPWeightsUnavailable) as err:
        build_clip_model(str(path), "ViT-S-16-alt")
    message = str(err.value)
    assert "open_clip ViT-S-16-alt" in message and str(path) in message and "\n" not in message, message


def test_offline_pretrained_tag_lists_the_models_options(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(clip_weights, "_cached_pretrained_file", lambda model_name, tag: None)
    monkeypatch.setattr(clip_weights, "_hub_reachable", lambda timeout_s=3.0: False)
    start = time.monotonic()
    with pytest.raises(CLIPWeightsUnavailable) as err:
        build_clip_model("openai", "RN101-quickgelu")
    assert time.monotonic() - start < 10
    message = str(err.value)
    assert "RN101.pt" in message and "RN101-quickgelu" in message and "openai, yfcc15m" in message, message
    with pytest.raises(CLIPWeightsUnavailable) as err:
        build_clip_model("laion5b", "ViT-B-16")
    assert "laion2b_s34b_b88k" in str(err.value) and "ViT-B-16.pt" in str(err.value)


def test_hub_tokenizer_offline_is_one_user_error_line(tmp_path: Path) -> None:
    """A ViT whose tokenizer is a Hugging Face one, with an empty HF cache and the hub off: one line, fast.

    In a fresh interpreter, since huggingface_hub reads HF_HOME and HF_HUB_OFFLINE when it is imported.
    """
    script = (
        "from cliport.models.encoders.clip_encoder import load_clip\n"
        "from cliport.models.encoders.clip_tokenizer import TokenizerUnavailable\n"
        "try:\n"
        "    load_clip('random', 'ViT-H-14-CLIPA')\n"
        "except TokenizerUnavailable as err:\n"
        "    print('ERROR', err)\n"
    )
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": str(tmp_path / "hf")}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    lines = done.stdout.strip().splitlines()
    assert done.returncode == 0 and len(lines) == 1 and lines[0].startswith("ERROR "), (done.stdout, done.stderr)
    assert "ViT-H-14-CLIPA" in lines[0] and "HF_HOME" in lines[0], lines[0]
    assert "Traceback" not in done.stderr, done.stderr
