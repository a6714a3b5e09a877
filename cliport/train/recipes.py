"""Training recipes: what each paper's code does in a training step, as named bundles.

The nets are the reference's either way; the recipes differ in the loss, Adam's epsilon, whether the frozen
encoder's batch norms train, and the augmentation's pivot and interpolation. Values live in
``configs/recipes.toml``; ``cliport-train --recipe NAME`` picks one and the run records it.

Why the loss matters under Adam: CLIPort's loss is the cross-entropy divided by the map's cells (51,200 for
a 320 x 160 pick map, 1,843,200 for 36 place rotations). Adam's step is lr * m / (sqrt(v) + eps); with
per-parameter gradients far below eps = 1e-8, that is about lr / eps times the gradient, i.e. SGD with
momentum at a rate of lr / (eps * cells) on the cross-entropy, instead of Adam's scale-free step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from cliport.data.augment import INTERPOLATIONS, PIVOTS
from cliport.errors import ConfigError, UnknownNameError
from cliport.utils.config import from_dict, read_defaults

if TYPE_CHECKING:  # recipes are read without torch (the training config, the console scripts' flags)
    import torch

    from cliport.agents.base import PickPlaceAgent

#: Loss reductions: ``cell_mean``, the cross-entropy over each map divided by its cells (the reference CLIPort's
#: ``cross_entropy_with_logits(reduction='mean')``); ``sample_ce``, the per-sample cross-entropy (Ravens').
#: Both are averaged over the batch.
LOSSES = ("cell_mean", "sample_ce")
#: ``train``: the frozen encoder's batch norms normalise with each training sample's own statistics and update
#: their running statistics (per net) in training steps, as the reference CLIPort's ``attention.train()``
#: does; ``frozen``: inference mode always.
ENCODER_NORMS = ("train", "frozen")


@dataclass(frozen=True)
class Recipe:
    """One training recipe (a table of ``configs/recipes.toml``).

    Args:
        name: the recipe's name (its table).
        loss: cell_mean or sample_ce (see LOSSES).
        adam_eps: Adam's epsilon (the learning rate is the agent's ``lr``).
        encoder_norms: train or frozen (see ENCODER_NORMS); train needs per-net statistics.
        aug_pivot: the augmentation's rotation pivot (half_size or centre).
        aug_interpolation: the augmentation's interpolation (linear or nearest).
    """

    name: str
    loss: str
    adam_eps: float
    encoder_norms: str
    aug_pivot: str
    aug_interpolation: str

    def prepare(self, agent: PickPlaceAgent) -> tuple[torch.optim.Optimizer, int]:
        """Set the agent's encoder batch-norm mode and build its optimiser with this recipe's epsilon; returns
        the optimiser and how many nets train their encoder's batch norms. Steps then take ``loss=self.loss``
        (:meth:`PickPlaceAgent.compute_loss`)."""
        applied = agent.set_encoder_norm_training(self.encoder_norms == "train")
        if applied:
            _check_query_norm_statistics(self.name, agent)
        return agent.make_optimizer(eps=self.adam_eps), applied

    def __post_init__(self) -> None:
        for field, value, allowed in (
            ("loss", self.loss, LOSSES),
            ("encoder_norms", self.encoder_norms, ENCODER_NORMS),
            ("aug_pivot", self.aug_pivot, PIVOTS),
            ("aug_interpolation", self.aug_interpolation, INTERPOLATIONS),
        ):
            if value not in allowed:
                raise ConfigError(f"recipe {self.name}: {field} must be one of {', '.join(allowed)}, got {value!r}")
        if not self.adam_eps > 0:
            raise ConfigError(f"recipe {self.name}: adam_eps must be > 0, got {self.adam_eps}")


#: How much CLIP's ResNet trunk shrinks an image by its last stage (layer4).
CLIP_TRUNK_STRIDE = 32


def _check_query_norm_statistics(recipe: str, agent: PickPlaceAgent) -> None:
    """A batch norm in training mode needs more than one value per channel. Training CLIP's batch norms per
    sample, the query net normalises one sample's R crops together, and a crop that CLIP's last stage shrinks
    to one cell leaves one value per channel when R is 1 (the reference would fail the same way)."""
    config = agent.config
    side = int(round(config.crop_size * config.map_scale))
    values = config.n_rotations * (side // CLIP_TRUNK_STRIDE) ** 2
    if values < 2:
        raise ConfigError(
            f"recipe {recipe} trains CLIP's batch norms per sample, but the place query's {side}-pixel crop "
            f"(crop_size {config.crop_size} x map_scale {config.map_scale}) with {config.n_rotations} "
            f"rotation(s) leaves {values} value per channel at CLIP's last stage (stride {CLIP_TRUNK_STRIDE}); "
            f"use a crop of at least {2 * CLIP_TRUNK_STRIDE} pixels after map_scale, 2 or more rotations, or the "
            "ravens recipe"
        )


def recipe_names() -> list[str]:
    """The recipes of ``configs/recipes.toml``, in file order."""
    return list(read_defaults("recipes"))


def get_recipe(name: str) -> Recipe:
    """The named recipe; UnknownNameError listing the recipes for another name."""
    tables = read_defaults("recipes")
    if name not in tables:
        raise UnknownNameError(f"unknown recipe {name!r}; choose one of {', '.join(tables)}")
    return from_dict(Recipe, {"name": name, **tables[name]}, "configs/recipes.toml")
