import logging
import time
import warnings
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from cliport.models.encoders import clip_encoder, clip_registry, clip_weights
from cliport.models.encoders.clip_encoder import FrozenCLIP, load_clip
from cliport.models.encoders.clip_tokenizer import CONTEXT_LENGTH, instruction_token_count
from cliport.models.encoders.clip_weights import CLIPWeightsUnavailable, build_clip_model


def _perturbed_state(clip: FrozenCLIP) -> dict[str, torch.Tensor]:
    # Differ from the seeded "random" init so that a silent fallback to it would be caught.
    gen = torch.Generator().manual_seed(123)
    return {
        k: (v + torch.randn(v.shape, generator=gen).to(v.dtype) if v.is_floating_point() else v).contiguous()
        for k, v in clip.model.state_dict().items()
    }


@pytest.mark.parametrize("suffix", [".pt", ".safetensors"])
def test_state_dict_file_round_trip(clip: FrozenCLIP, tmp_path: Path, suffix: str) -> None:
    state = _perturbed_state(clip)
    path = tmp_path / f"rn50{suffix}"
    if suffix == ".pt":
        torch.save(state, path)
    else:
        save_file(state, str(path))
    loaded = load_clip(str(path))
    assert loaded.source == str(path)
    got = loaded.model.state_dict()
    assert got.keys() == state.keys()
    for k, v in state.items():
        assert torch.equal(got[k], v), k


def test_openai_fails_fast_and_clearly_offline(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(clip_weights, "_cached_pretrained_file", lambda model_name, tag: None)
    monkeypatch.setattr(clip_weights, "_hub_reachable", lambda timeout_s=3.0: False)
    start = time.monotonic()
    with pytest.raises(CLIPWeightsUnavailable) as err:
        build_clip_model("openai")
    assert time.monotonic() - start < 10
    message = str(err.value)
    assert "clip_weights" in message and "random" in message and "RN50.pt" in message


def test_hub_is_unreachable_when_hf_offline_is_set(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    assert not clip_weights._hub_reachable()


def test_missing_file_is_an_error_not_a_fallback(tmp_path: Path) -> None:
    with pytest.raises(CLIPWeightsUnavailable):
        build_clip_model(str(tmp_path / "nope.pt"))


def test_random_init_is_reproducible(clip: FrozenCLIP) -> None:
    again = build_clip_model("random")
    for (k, v), w in zip(clip.model.state_dict().items(), again.state_dict().values(), strict=True):
        assert torch.equal(v, w), k


def test_frozen_stays_in_eval_mode_without_grads(clip: FrozenCLIP) -> None:
    clip.train()
    assert not clip.training and not any(m.training for m in clip.modules())
    assert not any(p.requires_grad for p in clip.parameters())


def test_image_features_shapes(clip: FrozenCLIP) -> None:
    feats = clip.image_features(torch.rand(2, 3, 64, 96))
    shapes = [tuple(f.shape) for f in feats]
    assert shapes == [(2, 64, 16, 24), (2, 256, 16, 24), (2, 512, 8, 12), (2, 1024, 4, 6), (2, 2048, 2, 3)]
    assert not any(f.requires_grad for f in feats)


def test_sentence_features_are_cached_per_string(clip: FrozenCLIP) -> None:
    feats = clip.sentence_features(["pack the box", "push the pile", "pack the box"])
    assert feats.shape == (3, 1024)
    assert torch.equal(feats[0], feats[2])
    assert not torch.allclose(feats[0], feats[1])
    assert "pack the box" in clip._sentence_cache


def test_random_trunk_features_are_unit_scale(clip: FrozenCLIP) -> None:
    """Calibrated batch norms: a random trunk's features do not vanish with depth (they shrank ~1000x)."""
    feats = clip.image_features(torch.rand(2, 3, 64, 96, generator=torch.Generator().manual_seed(1)))
    scales = [f.abs().mean().item() for f in feats]
    assert all(0.1 < s < 10 for s in scales), scales
    norms = [m for m in clip.model.visual.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert all(m.momentum == 0.1 and not m.training for m in norms)


def test_random_build_logs_and_warns_nothing(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.DEBUG), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        build_clip_model("random")
    assert [r.getMessage() for r in caplog.records] == []
    assert [str(w.message) for w in caught] == []


def test_open_clip_warnings_still_pass_outside_the_random_case(caplog: pytest.LogCaptureFixture) -> None:
    """The filter drops exactly the intended records: open_clip's own warning stays visible elsewhere."""
    with caplog.at_level(logging.INFO), clip_registry.quiet_open_clip(expect_random_init=False):
        import open_clip

        open_clip.create_model(clip_registry.MODEL_NAME, pretrained=None)
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 1 and "initialized randomly" in messages[0]


def _garbage(tmp_path: Path, kind: str, clip: FrozenCLIP) -> tuple[Path, str]:
    """A state dict of another model, or CLIP's with one wrong shape, and a phrase its error must contain."""
    if kind == "other-model":
        path = tmp_path / "rn50.safetensors"
        save_file(torch.nn.Linear(2, 2).state_dict(), str(path))
        return path, "missing (e.g. positional_embedding)"
    assert kind == "wrong-shape"
    state = dict(clip.model.state_dict())
    state["text_projection"] = torch.zeros(512, 512)
    path = tmp_path / "rn50.pt"
    torch.save(state, path)
    return path, "text_projection: (512, 512) instead of (512, 1024)"


BAD_FILE_KINDS = [
    *("random-bytes", "truncated", "empty", "fake-safetensors", "pickled-module", "not-a-dict"),
    *("other-model", "wrong-shape"),
]


@pytest.mark.parametrize("kind", BAD_FILE_KINDS)
def test_bad_weights_file_is_one_clear_line(clip: FrozenCLIP, tmp_path: Path, kind: str, bad_weight_file) -> None:
    path, reason = bad_weight_file(kind, "rn50") or _garbage(tmp_path, kind, clip)
    with pytest.raises(CLIPWeightsUnavailable) as err:
        build_clip_model(str(path))
    message = str(err.value)
    assert str(path) in message and reason in message, message
    assert "\n" not in message and "weights_only" not in message and len(message) < 300, message


def test_instruction_token_count() -> None:
    assert CONTEXT_LENGTH == 77
    assert instruction_token_count("pack the box") == 5  # start, three words, end
    assert instruction_token_count("red " * 80) == 82


def test_long_instruction_warns_once_with_its_token_count(clip: FrozenCLIP, caplog: pytest.LogCaptureFixture) -> None:
    long = "put the " + "very " * 80 + "red block in the green bowl"
    short = "put the red block in the green bowl"
    with caplog.at_level(logging.WARNING, logger=clip_encoder.__name__):
        clip.sentence_features([long, short])
        clip._sentence_cache.clear()  # encoding it again must not repeat the warning
        clip.sentence_features([long])
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1, warned
    assert f"{instruction_token_count(long)} CLIP tokens" in warned[0] and long in warned[0]


def test_default_is_clip_rn50_with_its_widths(clip: FrozenCLIP) -> None:
    assert clip.model_name == clip_registry.MODEL_NAME == "RN50-quickgelu"
    assert clip.trunk_channels == clip_encoder.TRUNK_CHANNELS == (64, 256, 512, 1024, 2048)
    assert clip.sentence_dim == clip_encoder.SENTENCE_DIM == 1024
    assert clip.context_length == CONTEXT_LENGTH and clip.vit_blocks is None
