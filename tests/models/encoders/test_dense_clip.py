"""Dense text-aligned embeddings: at the attention pool's own grid, the pooled image embedding is the average of
the dense ones wherever the pool attends uniformly; published-size RN50 weights from a file take the same path."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from cliport.models.encoders.clip_encoder import FrozenCLIP, load_clip
from cliport.models.encoders.dense_clip import dense_embeddings, similarity_map


def _uniform_attention(visual: torch.nn.Module) -> torch.nn.Module:
    """A copy of ``visual`` whose attention pool attends to every token alike (queries and keys zero)."""
    uniform = copy.deepcopy(visual)
    pool = uniform.attnpool
    for proj in (pool.q_proj, pool.k_proj):
        torch.nn.init.zeros_(proj.weight)
        torch.nn.init.zeros_(proj.bias)
    return uniform


def _pooled_as_dense_mean(visual: torch.nn.Module, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The tower's pooled embedding of ``image`` (N, 3, S, S) at its own size, and the mean of its dense
    embeddings over the pool's tokens: the mean token (projected likewise) and every position."""
    with torch.no_grad():
        layer4 = visual.forward_intermediates(image, intermediates_only=True)["image_intermediates"][-1]
        pooled = visual.attnpool(layer4)
        dense = dense_embeddings(visual, layer4)  # (N, E, h, w)
        pool = visual.attnpool
        mean_token = layer4.mean(dim=(2, 3)) + pool.positional_embedding[0]
        mean_dense = pool.c_proj(pool.v_proj(mean_token))
        n_tokens = dense.shape[2] * dense.shape[3] + 1
        return pooled, (dense.sum(dim=(2, 3)) + mean_dense) / n_tokens


def test_pooled_embedding_is_the_dense_average_under_uniform_attention() -> None:
    encoder = load_clip("random", "cliport-RN-tiny")
    visual = _uniform_attention(encoder.model.visual)
    size = visual.image_size if isinstance(visual.image_size, int) else visual.image_size[0]
    image = torch.randn(2, 3, size, size, generator=torch.Generator().manual_seed(0))
    pooled, average = _pooled_as_dense_mean(visual, image)
    assert pooled.shape == average.shape == (2, encoder.sentence_dim)
    torch.testing.assert_close(average, pooled, rtol=1e-4, atol=1e-5)


def test_dense_embeddings_at_another_grid_keep_the_text_width_and_vary_by_position() -> None:
    encoder = load_clip("random", "cliport-RN-tiny")
    image = torch.rand(1, 3, 160, 96, generator=torch.Generator().manual_seed(1))
    layer4 = encoder.image_features(image)[-1]
    dense = dense_embeddings(encoder.model.visual, layer4)
    assert dense.shape == (1, encoder.sentence_dim, *layer4.shape[-2:])
    assert dense.flatten(2).std(dim=2).mean() > 0  # not one vector repeated


def test_similarity_map_is_cosine_per_position() -> None:
    text = torch.tensor([[1.0, 0.0], [0.0, 2.0]])
    dense = torch.zeros(2, 2, 1, 3)
    dense[0, :, 0] = torch.tensor([[3.0, 0.0, -1.0], [0.0, 3.0, 0.0]])  # along, across, against the text
    dense[1, :, 0] = torch.tensor([[1.0, 1.0, 0.0], [1.0, 0.0, 5.0]])
    got = similarity_map(dense, text[:, None])
    assert got.shape == (2, 1, 1, 3)
    torch.testing.assert_close(got[0, 0, 0], torch.tensor([1.0, 0.0, -1.0]))
    torch.testing.assert_close(got[1, 0, 0], torch.tensor([2**-0.5, 0.0, 1.0]))
    with pytest.raises(ValueError, match="differ in N or E"):
        similarity_map(dense, text[:, None, :1])


def test_rn50_weights_from_a_file_take_the_same_path(clip: FrozenCLIP, tmp_path: Path) -> None:
    """CLIPort's RN50 from a weights file written here (as published weights are read): its dense embeddings
    have the text's 1024 channels and, under uniform attention, average to its own pooled embedding."""
    gen = torch.Generator().manual_seed(7)
    state = {  # the weights moved, the batch-norm statistics kept (a variance must stay positive)
        k: (v + 0.01 * torch.randn(v.shape, generator=gen) if v.is_floating_point() and "running" not in k else v)
        for k, v in clip.model.state_dict().items()
    }
    state = {k: v.contiguous() for k, v in state.items()}
    path = tmp_path / "rn50.safetensors"
    save_file(state, str(path))
    loaded = load_clip(str(path))
    assert loaded.source == str(path)
    visual = _uniform_attention(loaded.model.visual)
    image = torch.randn(1, 3, 224, 224, generator=gen)
    pooled, average = _pooled_as_dense_mean(visual, image)
    assert pooled.shape == (1, 1024) == (1, loaded.sentence_dim)
    torch.testing.assert_close(average, pooled, rtol=1e-4, atol=1e-4)
    random_pooled, _ = _pooled_as_dense_mean(_uniform_attention(clip.model.visual), image)
    assert not torch.allclose(random_pooled, pooled)  # the file's weights, not the random ones


def test_vit_tokens_take_the_final_norm_and_projection() -> None:
    encoder = load_clip("random", "ViT-S-32-alt")
    visual = encoder.model.visual
    layer4 = torch.randn(1, visual.proj.shape[0], 2, 3)
    dense = dense_embeddings(visual, layer4)
    assert dense.shape == (1, visual.proj.shape[1], 2, 3)
    token = layer4[0, :, 1, 2]
    torch.testing.assert_close(dense[0, :, 1, 2], visual.ln_post(token) @ visual.proj)


def test_a_tower_without_a_pool_or_projection_is_one_clear_error() -> None:
    with pytest.raises(ValueError, match="no dense embeddings for an image tower of type Identity"):
        dense_embeddings(torch.nn.Identity(), torch.zeros(1, 4, 2, 2))


def test_bank_probability_is_a_softmax_against_the_other_entries() -> None:
    from cliport.models.encoders.dense_clip import bank_probability

    dense = torch.zeros(1, 2, 1, 2)
    dense[0, :, 0, 0] = torch.tensor([1.0, 0.0])  # along the first axis
    dense[0, :, 0, 1] = torch.tensor([0.0, 1.0])  # along the second
    bank = torch.tensor([[1.0, 0.0], [0.0, 1.0], [5.0, 5.0]])
    valid = torch.tensor([True, True, False])  # the third row is no entry
    texts = torch.tensor([[[2.0, 0.0], [0.0, 0.0]]])  # the first entry itself (left out of its own softmax), a zero
    got = bank_probability(dense, texts, bank, valid, logit_scale=10.0)
    assert got.shape == (1, 2, 1, 2)
    e = torch.exp(torch.tensor(10.0))
    torch.testing.assert_close(got[0, 0, 0], torch.stack([e / (e + 1), 1 / (1 + e)]))
    torch.testing.assert_close(got[0, 1], torch.zeros(1, 2))


def test_a_phrase_bank_holds_the_instructions_and_their_phrases(clip: FrozenCLIP) -> None:
    from cliport.models.encoders.dense_clip import PhraseBank

    bank = PhraseBank(clip.sentence_dim)
    assert not bank.fitted
    held = bank.fit(clip, ["put the red block in the green bowl", "put the blue block in the green bowl"])
    assert held == 3 and bank.fitted and int(bank.valid.sum()) == 3  # the three distinct phrases
    torch.testing.assert_close(bank.embeddings[:3].norm(dim=1), torch.ones(3))
    again = PhraseBank(clip.sentence_dim)
    again.load_state_dict(bank.state_dict())
    assert again.fitted
    with pytest.raises(ValueError, match="holds 1 to 256 phrases, got 0"):
        bank.fit(clip, [])
