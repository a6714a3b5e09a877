"""``center_sentences``: language agents reading sentence features centred on their training instructions."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent
from cliport.errors import ConfigError

COLOURS = ["red", "green", "blue", "yellow"]
TEXTS = [f"put the {a} block in the {b} bowl" for a in COLOURS for b in COLOURS if a != b]


@pytest.fixture(scope="module")
def centred(tiny_config):
    torch.manual_seed(0)
    return make_agent("two_stream", tiny_config("two_stream", center_sentences=True, semantic_encoder="RN50-quickgelu"))


def test_unfitted_centring_is_refused_and_fitting_centres_and_keeps_the_norm(centred) -> None:
    with pytest.raises(RuntimeError, match=r"fit_sentence_centering"):
        centred.sentence_features(TEXTS[:1])
    fitted = centred.fit_sentence_centering(TEXTS + TEXTS[:3])  # repeats count once
    assert fitted["instructions"] == len(TEXTS) and fitted["scale"] > 1
    raw = centred.encoder.sentence_features(TEXTS)
    features = centred.sentence_features(TEXTS)
    assert features.mean(0).abs().max() < 1e-4 * raw.norm(dim=1).mean()
    assert features.pow(2).sum(1).mean().sqrt() == pytest.approx(float(raw.pow(2).sum(1).mean().sqrt()), rel=1e-5)
    # What the sentences share is gone: they are far less alike than the raw features.
    cosine = torch.nn.functional.cosine_similarity
    assert cosine(features[0], features[1], dim=0) < cosine(raw[0], raw[1], dim=0) - 0.2


def test_centring_is_saved_with_the_weights_and_recorded(centred, tmp_path: Path) -> None:
    centred.fit_sentence_centering(TEXTS)
    path = tmp_path / "agent.pt"
    centred.save_checkpoint(path)
    payload = torch.load(path, weights_only=True)
    assert payload["config"]["center_sentences"] is True
    assert float(payload["state_dict"]["sentence_scale"]) > 1
    loaded = PickPlaceAgent.from_pretrained(path)
    torch.testing.assert_close(loaded.sentence_features(TEXTS[:2]), centred.sentence_features(TEXTS[:2]))


def test_checkpoints_without_the_setting_load_as_the_reference_reads_sentences(tiny_config, tmp_path: Path) -> None:
    agent = make_agent("two_stream", tiny_config("two_stream"))
    payload = agent.checkpoint_payload()
    del payload["config"]["center_sentences"]  # written before the setting existed
    torch.save(payload, tmp_path / "old.pt")
    loaded = PickPlaceAgent.from_pretrained(tmp_path / "old.pt")
    assert loaded.config.center_sentences is False and "sentence_scale" not in loaded.state_dict()
    torch.testing.assert_close(loaded.sentence_features(TEXTS[:1]), loaded.encoder.sentence_features(TEXTS[:1]))


def test_bad_uses_are_refused(centred, tiny_config) -> None:
    with pytest.raises(ValueError, match="at least two distinct instructions"):
        centred.fit_sentence_centering(["pack the box", "pack the box", ""])
    with pytest.raises(ValueError, match="center_sentences is off"):
        make_agent("clip_only", tiny_config("clip_only")).fit_sentence_centering(TEXTS)
    with pytest.raises(ConfigError, match="center_sentences"):
        make_agent("transporter_only", tiny_config("transporter_only", center_sentences=True))
