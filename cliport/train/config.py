"""The training config: run settings with the agent's and the workcell's settings nested inside, and the saved
config of a run folder (:func:`load_run_config`). Nothing here imports an agent or torch: the console scripts'
flags and ``--help`` come from these classes, and evaluation reads a run's config without the trainer."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cliport.agents.config import AgentConfig
from cliport.agents.registry import _resolve_agent
from cliport.env.config import EnvConfig, check_renderer
from cliport.errors import ConfigError, RunDirError
from cliport.train.recipes import Recipe, get_recipe, recipe_names
from cliport.utils.config import defaults_file, from_dict, merge, read_defaults, to_dict
from cliport.utils.files import read_json
from cliport.utils.run_dir import RunDir


@dataclass
class TrainConfig:
    """A training run; defaults in ``configs/train.toml``, ``configs/<agent>.toml`` and ``configs/env.toml``.

    Args:
        agent: registered agent name (``cliport-train --help`` lists them).
        task: task name or multi-task group to train on.
        n_demos: training episodes per task (the first n of a seeded shuffle of the demo folder).
        n_steps: optimiser steps.
        batch_size: samples per step (the reference trains at 1; lr is not rescaled).
        data_dir: folder of the demonstrations (``cliport-demos --data-dir``).
        run_dir: output folder; empty for runs/TASK-AGENT-nN-sSEED.
        device: auto (CUDA when available), cpu, cuda, cuda:1, ...
        seed: seed of the demo subset, initialisation, sampling and augmentation.
        num_workers: DataLoader worker processes.
        amp: auto (bf16 autocast on GPUs that compute bf16 natively, compute capability 8.0+; else none), bf16
            or none.
        checkpoint_steps: steps to save checkpoints at (then every checkpoint_every steps).
        checkpoint_every: steps between checkpoints after the listed ones (0: none).
        save_last_every: steps between rolling resume points (checkpoints/last.pt).
        log_every: steps between rows of metrics.csv.
        val_episodes: val episodes per checkpoint (0: no validation).
        rotation_aug: standard deviation (degrees) of the random rotation of the SE(2) training augmentation
            (the reference's 60 for every task); 0 turns rotation off (random shifts stay), e.g. for tasks
            whose instructions name directions ("left", "forward") that a rotated image contradicts.
        val_workers: simulator processes validating each checkpoint (the agent acts on their episodes in one
            batch); unset: the usable CPU cores, at most 8 and at most val_episodes.
        val_mode: when checkpoints are validated: beside (in a background process while training goes on),
            after (all once training ends) or auto (beside on CUDA, after on a CPU).
        recipe: the training recipe, a table of configs/recipes.toml: cliport (the reference CLIPort's code:
            the loss averaged over every map cell, Adam eps 1e-8, CLIP's batch norms training per net,
            bilinear augmentation about (W/2, H/2)), ravens (Transporter Networks' code: the per-sample
            cross-entropy, Adam eps 1e-7, nearest-neighbour augmentation about (W/2, H/2)) or legacy (cliport
            0.2's training, before recipes existed in 0.3.0). A run keeps its recipe when resumed.
        every_instruction: train on every instruction the demos record for each step (``cliport-demos
            --every-instruction``), each with the oracle's action for it, not only the one each scene was built
            with: the same image under other sentences and other answers. Not the reference's.
        pair_contrasts: each training sample is followed by the same scene, with the same augmentation, under an
            instruction that names another pick and another place (with ``every_instruction``; the two are
            consecutive steps at batch 1, :class:`~cliport.train.loader.ContrastPairSampler`). Not the reference's.
        train_graphs: on CUDA, replay each training step as one CUDA graph at the run's batch shape (forward,
            loss, backward, fused Adam; :mod:`cliport.train.graphed_step`); a step of another shape, a CPU and
            DDP train eagerly. Off: every step eagerly.
        compile: run the agent's loss through ``torch.compile`` (forward and loss fused into generated kernels,
            the backward through AOTAutograd), inside the captured graph on CUDA; the first steps compile
            (minutes at the published size). Off by default; single-process runs only.
        time_budget_s: stop training once this many seconds of the training loop (its checks and saves
            included, summed over resumes) have passed, at most ``n_steps``; 0: no budget. The step it stops at is
            checkpointed as ``n_steps`` would be. The step count then depends on the machine's speed.
        lr_cooldown: the learning rate falls linearly to zero over this last fraction of the run (of ``n_steps``,
            or of ``time_budget_s`` where that ends the run first: :mod:`cliport.train.lr_schedule`); 0: constant,
            the reference's. On CUDA it turns ``train_graphs`` off (a captured step holds its rate fixed).
        parallel_heads: on the CPU, each eager step differentiates the pick net's and the place nets' halves of the
            loss at once, in two threads with half the intra-op threads each (one backward elsewhere, and with
            ``compile``); the same gradients to float rounding, a step ~0.65x the time on 2 cores
            (docs/language-lesson.md). Not under DDP.
        agent_config: the agent's own settings (its config class; defaults in configs/<agent>.toml).
        env: workcell settings of the validation episodes (defaults in configs/env.toml).
    """

    agent: str
    task: str
    n_demos: int
    n_steps: int
    batch_size: int
    data_dir: str
    run_dir: str
    device: str
    seed: int
    num_workers: int
    amp: str
    checkpoint_steps: list[int]
    checkpoint_every: int
    save_last_every: int
    log_every: int
    val_episodes: int
    agent_config: AgentConfig
    env: EnvConfig
    # A default only so that config.json files of runs that predate the field load (they trained with 60).
    rotation_aug: float = 60.0
    val_workers: int | None = None
    val_mode: str = "auto"
    # Runs saved before recipes existed trained with what configs/recipes.toml calls legacy.
    recipe: str = "legacy"
    every_instruction: bool = False
    pair_contrasts: bool = False
    # Defaults only so that config.json files of runs saved before these settings existed load.
    train_graphs: bool = True
    compile: bool = False
    parallel_heads: bool = False
    time_budget_s: float = 0.0
    lr_cooldown: float = 0.0

    @classmethod
    def build(cls, overrides: Mapping[str, Any] | None = None, base: Mapping[str, Any] | None = None) -> TrainConfig:
        """``base`` (default: configs/train.toml) updated with ``overrides`` (nested dicts), checked.

        The agent's settings start from ``configs/<agent>.toml`` and the workcell's from ``configs/env.toml``; an
        agent setting the agent does not have is a ConfigError (``cliport.agents.registry._resolve_agent``).
        """
        source = "saved config" if base is not None else defaults_file("train")
        data = merge(dict(base) if base is not None else read_defaults("train"), overrides or {})
        if not isinstance(data.get("agent"), str):
            raise ConfigError(f"{source}: agent must be an agent name, got {data.get('agent')!r}")
        agent_config_class = _resolve_agent(data["agent"], data.get("agent_config", {}))
        if base is None:
            data["agent_config"] = merge(read_defaults(data["agent"]), data.get("agent_config", {}))
            data["env"] = merge(read_defaults("env"), data.get("env", {}))
        config = from_dict(cls, data, source, nested={"agent_config": agent_config_class})
        config.validate()
        if config.training_recipe().encoder_norms == "train" and hasattr(config.agent_config, "per_net_clip_stats"):
            # Training CLIP's batch norms needs each net's own statistics, saved with its weights.
            config.agent_config.per_net_clip_stats = True
        return config

    def training_recipe(self) -> Recipe:
        """The :class:`~cliport.train.recipes.Recipe` named by ``recipe``."""
        return get_recipe(self.recipe)

    @classmethod
    def from_saved(cls, data: Mapping[str, Any], overrides: Mapping[str, Any] | None = None) -> TrainConfig:
        """A run's saved config.json (older flat layouts upgraded) updated with ``overrides``."""
        return cls.build(overrides, base=upgrade_saved_config(data))

    def validate(self) -> None:
        """Raise ConfigError for settings no run can use."""
        minimum = {
            "n_demos": 1,
            "n_steps": 1,
            "batch_size": 1,
            "num_workers": 0,
            "save_last_every": 1,
            "log_every": 1,
            "val_episodes": 0,
            "checkpoint_every": 0,
            "rotation_aug": 0,
            "time_budget_s": 0,
        }
        for key, low in minimum.items():
            if getattr(self, key) < low:
                raise ConfigError(f"{key} must be >= {low}, got {getattr(self, key)}")
        if not 0 <= self.lr_cooldown <= 1:
            raise ConfigError(f"lr_cooldown is a fraction of the run, from 0 to 1, got {self.lr_cooldown}")
        if self.val_mode not in ("auto", "after", "beside"):
            raise ConfigError(f"val_mode must be auto, after or beside, got {self.val_mode!r}")
        if self.amp not in ("auto", "bf16", "none"):
            raise ConfigError(f"amp must be auto, bf16 or none, got {self.amp!r}")
        if self.pair_contrasts and not self.every_instruction:
            raise ConfigError("pair_contrasts pairs the instructions of a scene: it needs every_instruction")
        if self.env.camera_scale <= 0:
            raise ConfigError(f"camera_scale must be > 0, got {self.env.camera_scale}")
        check_renderer(self.env.renderer)
        self.agent_config.validate()
        if self.recipe not in recipe_names():
            raise ConfigError(f"unknown recipe {self.recipe!r}; choose one of {', '.join(recipe_names())}")

    def resolved_run_dir(self) -> str:
        """The run folder: ``run_dir``, or ``runs/TASK-AGENT-nN-sSEED`` when it is empty."""
        return self.run_dir or os.path.join("runs", f"{self.task}-{self.agent}-n{self.n_demos}-s{self.seed}")

    def to_dict(self) -> dict[str, Any]:
        """The config as nested plain dicts (what ``RUN/config.json`` holds)."""
        return to_dict(self)


def load_run_config(run_dir: str) -> TrainConfig:
    """The resolved config a run saved (any layout version); RunDirError if the folder is not a run."""
    run = RunDir(run_dir)
    if not os.path.isdir(run_dir):
        raise RunDirError(f"run folder not found: {run_dir}")
    if not run.is_run():
        raise RunDirError(f"{run_dir} is not a training run (no config.json)")
    return TrainConfig.from_saved(read_json(run.config))


def upgrade_saved_config(data: Mapping[str, Any]) -> dict[str, Any]:
    """A config.json of any version as the current nested layout (runs saved before it was nested kept
    ``lr``, ``clip_weights`` and ``agent_overrides`` beside the run settings and ``camera_scale`` at the top)."""
    data = dict(data)
    if "agent_config" in data:
        return data
    agent_config = dict(read_defaults(data["agent"]))
    agent_config.update(data.pop("agent_overrides", None) or {})
    for key in ("lr", "clip_weights"):
        value = data.pop(key, None)
        if value is not None and key in agent_config:
            agent_config[key] = value
    env = dict(read_defaults("env"))
    if "camera_scale" in data:
        env["camera_scale"] = data.pop("camera_scale")
    data["run_dir"] = data.get("run_dir") or ""
    data["agent_config"], data["env"] = agent_config, env
    return data
