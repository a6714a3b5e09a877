"""gate_phrase_dropout: the sentence the gates read loses a phrase's describing words at random in training, and
at act time wherever the phrase bank lacks the phrase; the maps still read every phrase."""

from __future__ import annotations

import pytest
import torch

from cliport.agents import make_agent, sentences
from cliport.errors import ConfigError
from cliport.models.encoders.dense_clip import without_describing_words

SEEN = ["put the red block in the green bowl", "put the blue block in the yellow bowl"]


def test_a_phrase_keeps_its_article_and_last_word() -> None:
    text = "put the pink block in the red bowl"
    assert without_describing_words(text, [True, False]) == "put the block in the red bowl"
    assert without_describing_words(text, [True, True]) == "put the block in the bowl"
    assert without_describing_words(text, [False, False]) == text  # nothing cut: the instruction as given
    assert without_describing_words("Put the light blue block, in a bowl.", [True]) == "put the block in a bowl"
    assert without_describing_words("pick up the block", [True]) == "pick up the block"  # no describing word


@pytest.fixture
def agent(tiny_config):
    torch.manual_seed(0)
    config = tiny_config(
        "two_stream", semantic_encoder="cliport-RN-tiny", similarity_maps=True, similarity_bank=True,
        gate_phrase_dropout=0.5,
    )  # fmt: skip
    agent = make_agent("two_stream", config)
    agent.phrase_bank.fit(agent.encoder, SEEN)
    return agent


def test_at_act_time_the_gates_read_only_the_phrases_the_bank_holds(agent) -> None:
    agent.eval()
    dim = agent.encoder.sentence_dim
    unseen = "put the pink block in the green bowl"
    assert agent.phrase_bank.holds(agent.encoder, ["the pink block", "the green bowl"]) == [False, True]
    features = agent.sentence_features([unseen, SEEN[1]])
    expected = agent.encoder.sentence_features(["put the block in the green bowl", SEEN[1]])
    torch.testing.assert_close(features[:, :dim], expected)
    # The maps read the instruction's own phrases, the unseen colour included.
    maps = sentences.similarity_texts(agent.encoder, [unseen, SEEN[1]])
    torch.testing.assert_close(features[:, dim:], maps)


def test_in_training_each_phrase_is_cut_at_the_rate_and_by_the_seed(agent) -> None:
    agent.train()
    texts = [SEEN[0]] * 400
    torch.manual_seed(1)
    first = sentences.gate_texts(agent.encoder, texts, 0.5, agent.phrase_bank, training=True)
    torch.manual_seed(1)
    assert sentences.gate_texts(agent.encoder, texts, 0.5, agent.phrase_bank, training=True) == first
    cut = sum(("red" not in t) + ("green" not in t) for t in first) / (2 * len(texts))
    assert 0.42 < cut < 0.58
    assert set(first) == {SEEN[0], "put the block in the green bowl", "put the red block in the bowl",
                          "put the block in the bowl"}  # fmt: skip
    assert sentences.gate_texts(agent.encoder, texts, 0.0, agent.phrase_bank, training=True) == texts


def test_it_needs_the_bank_and_the_gates(tiny_config) -> None:
    base = {"semantic_encoder": "cliport-RN-tiny", "similarity_maps": True}
    with pytest.raises(ConfigError, match="gate_phrase_dropout needs similarity_bank"):
        make_agent("two_stream", tiny_config("two_stream", **base, gate_phrase_dropout=0.5))
    with pytest.raises(ConfigError, match="gate_phrase_dropout needs similarity_bank"):
        make_agent(
            "two_stream",
            tiny_config("two_stream", **base, similarity_bank=True, language_gates=False, gate_phrase_dropout=0.5),
        )
    with pytest.raises(ConfigError, match="a probability below 1, got 1.0"):
        make_agent("two_stream", tiny_config("two_stream", **base, similarity_bank=True, gate_phrase_dropout=1.0))
