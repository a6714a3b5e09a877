"""The training recipes: what each bundles, the losses' formulas, Adam's epsilon, CLIP's batch norms in
training steps, and how configs, checkpoints and resumes record them."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cliport.agents import make_agent
from cliport.errors import ConfigError, UnknownNameError
from cliport.train.config import TrainConfig
from cliport.train.recipes import Recipe, get_recipe, recipe_names

H, W = 64, 32


def _batch(n: int, seed: int = 0) -> dict[str, object]:
    rng = np.random.default_rng(seed)
    return {
        "color": torch.from_numpy(rng.integers(0, 256, (n, H, W, 3)).astype(np.uint8)),
        "height": torch.from_numpy(rng.random((n, H, W), dtype=np.float32) * 0.05),
        "pick_pix": torch.tensor([[10 + i, 5 + i] for i in range(n)]),
        "place_pix": torch.tensor([[40 - i, 20 - i] for i in range(n)]),
        "place_rot": torch.tensor([i % 8 for i in range(n)]),
        "lang": [f"put the {c} block in the bowl" for c in ("red", "blue", "green", "yellow")[:n]],
    }


def test_recipes_bundle_what_each_papers_code_does() -> None:
    assert recipe_names() == ["cliport", "ravens", "legacy"]
    cliport, ravens, legacy = (get_recipe(n) for n in recipe_names())
    assert (cliport.loss, cliport.adam_eps, cliport.encoder_norms) == ("cell_mean", 1e-8, "train")
    assert (cliport.aug_pivot, cliport.aug_interpolation) == ("half_size", "linear")
    assert (ravens.loss, ravens.adam_eps, ravens.encoder_norms) == ("sample_ce", 1e-7, "frozen")
    assert (ravens.aug_pivot, ravens.aug_interpolation) == ("half_size", "nearest")
    assert (legacy.loss, legacy.adam_eps, legacy.aug_pivot) == ("sample_ce", 1e-8, "centre")
    with pytest.raises(UnknownNameError, match="unknown recipe 'keras'; choose one of cliport, ravens, legacy"):
        get_recipe("keras")
    with pytest.raises(ConfigError, match="recipe x: loss must be one of cell_mean, sample_ce, got 'sum'"):
        Recipe("x", "sum", 1e-8, "frozen", "half_size", "nearest")


def test_losses_follow_their_formulas(tiny_config) -> None:
    torch.manual_seed(0)
    agent = make_agent("transporter_only", tiny_config("transporter_only"))
    agent.eval()
    batch = _batch(3)
    from cliport.models.preprocess import raw_input

    x = raw_input(batch["color"], batch["height"])
    with torch.no_grad():
        pick, place = agent.logits(x, batch["pick_pix"], None)
        sample_ce, info = agent.compute_loss(batch, "sample_ce")
        cell_mean, info_cells = agent.compute_loss(batch, "cell_mean")
    r = place.shape[1]
    pick_target = batch["pick_pix"][:, 0] * W + batch["pick_pix"][:, 1]
    place_target = (batch["place_rot"] * H + batch["place_pix"][:, 0]) * W + batch["place_pix"][:, 1]
    pick_lp, place_lp = F.log_softmax(pick.flatten(1), 1), F.log_softmax(place.flatten(1), 1)
    # Ravens: softmax cross-entropy per sample, then the batch mean.
    ravens = -(pick_lp.gather(1, pick_target[:, None]).mean() + place_lp.gather(1, place_target[:, None]).mean())
    assert float(sample_ce) == pytest.approx(float(ravens), rel=1e-5)
    # CLIPort: mean over every cell of -label * log_softmax, per net; batch mean.
    pick_label = F.one_hot(pick_target, H * W).float()
    place_label = F.one_hot(place_target, r * H * W).float()
    reference = (-pick_label * pick_lp).mean(1).mean() + (-place_label * place_lp).mean(1).mean()
    assert float(cell_mean) == pytest.approx(float(reference), rel=1e-5)
    assert info == info_cells  # both report the per-sample cross-entropies
    assert info["pick_loss"] == pytest.approx(float(-pick_lp.gather(1, pick_target[:, None]).mean()), rel=1e-5)


def test_prepare_sets_adams_epsilon_and_the_encoder_norm_mode(tiny_config) -> None:
    agent = make_agent("clip_only", tiny_config("clip_only", per_net_clip_stats=True))
    optimizer, applied = get_recipe("cliport").prepare(agent)
    assert applied == 3 and optimizer.param_groups[0]["eps"] == 1e-8
    optimizer, applied = get_recipe("ravens").prepare(agent)
    assert applied == 0 and optimizer.param_groups[0]["eps"] == 1e-7
    shared = make_agent("clip_only", tiny_config("clip_only"))
    assert get_recipe("cliport").prepare(shared)[1] == 0  # no per-net statistics: the shared trunk stays frozen


def test_cliport_recipe_refuses_a_query_crop_clip_shrinks_to_one_value(tiny_config) -> None:
    """The language lesson's CPU size (64-pixel crops at map_scale 0.5, one rotation) under the cliport recipe
    failed deep inside a batch norm ("Expected more than 1 value per channel when training"): one line instead."""
    one = tiny_config("clip_only", per_net_clip_stats=True, crop_size=64, map_scale=0.5, n_rotations=1)
    agent = make_agent("clip_only", one)
    with pytest.raises(ConfigError, match="32-pixel crop .* 1 rotation.* leaves 1 value per channel .* ravens recipe"):
        get_recipe("cliport").prepare(agent)
    assert get_recipe("ravens").prepare(agent)[1] == 0  # CLIP stays in inference mode: nothing to refuse
    two = make_agent("clip_only", {**one, "n_rotations": 2})
    assert get_recipe("cliport").prepare(two)[1] == 3


def test_cliport_recipe_trains_clip_batch_norms_per_sample_as_batch_1_steps(tiny_config) -> None:
    config = tiny_config("clip_only", per_net_clip_stats=True, n_rotations=2)
    torch.manual_seed(0)
    batched = make_agent("clip_only", config)
    sequential = copy.deepcopy(batched)
    frozen = copy.deepcopy(batched)
    for agent, recipe in ((batched, "cliport"), (sequential, "cliport"), (frozen, "ravens")):
        get_recipe(recipe).prepare(agent)
        agent.train()
    before = {k: v.clone() for k, v in batched.trainable_state_dict().items() if "encoder_stats" in k}
    batch = _batch(2)
    with torch.no_grad():
        batched.compute_loss(batch)
        frozen.compute_loss(batch)
        for i in range(2):
            sequential.compute_loss({k: v[i : i + 1] for k, v in batch.items()})
    after_batched, after_sequential = batched.trainable_state_dict(), sequential.trainable_state_dict()
    for key, value in before.items():
        # Two samples in one step move each net's running statistics as two batch-1 steps do.
        torch.testing.assert_close(after_batched[key], after_sequential[key], rtol=1e-5, atol=1e-7)
        assert torch.equal(frozen.trainable_state_dict()[key], value)
    assert sum(not torch.equal(after_batched[k], v) for k, v in before.items()) == len(before)
    # Acting reads the running statistics, in eval mode, whatever the recipe.
    scene = {"color": batch["color"][0].numpy(), "height": batch["height"][0].numpy()}
    assert batched.act(scene, batch["lang"][0])["pick_pix"] == sequential.act(scene, batch["lang"][0])["pick_pix"]


def test_train_config_records_the_recipe() -> None:
    base = {"agent": "clip_only", "task": "place-red-in-green", "agent_config": {"clip_weights": "random"}}
    cliport = TrainConfig.build({**base, "recipe": "cliport"})
    assert cliport.recipe == "cliport" and cliport.agent_config.per_net_clip_stats is True
    assert cliport.to_dict()["recipe"] == "cliport"
    ravens = TrainConfig.build({**base, "recipe": "ravens"})
    assert ravens.agent_config.per_net_clip_stats is False
    with pytest.raises(ConfigError, match="unknown recipe 'adam'; choose one of cliport, ravens, legacy"):
        TrainConfig.build({**base, "recipe": "adam"})
    saved = ravens.to_dict()
    del saved["recipe"]  # a run saved before recipes existed
    assert TrainConfig.from_saved(saved).recipe == "legacy"


def test_train_help_names_the_recipes() -> None:
    from cliport.cli.train import _parser

    text = " ".join(_parser()[0].format_help().split())
    assert "--recipe RECIPE" in text
    assert "cliport (the reference CLIPort's code" in text and "ravens (Transporter Networks' code" in text
