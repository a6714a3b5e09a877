"""The layout of a training run folder, in one place for training, evaluation, the study and the CLIs.

::

    RUN/config.json                      the resolved train config (agent, env and validation settings)
    RUN/model.safetensors                the newest scheduled checkpoint's trainable weights (safetensors, no
                                         pickle; agent, config and weight sources in its metadata)
    RUN/metrics.csv                      step, losses, throughput
    RUN/tensorboard/                     TensorBoard events of training (losses, learning rate, samples/s, GPU memory)
    RUN/tensorboard/val/                 TensorBoard events of validation (score and success with intervals)
    RUN/checkpoints/step-001000.pt ...   scheduled checkpoints (agent weights + config + weight sources)
    RUN/checkpoints/step-001000.safetensors ...  the same trainable weights as safetensors
    RUN/checkpoints/last.pt              rolling resume point (also optimiser, step and RNG state)
    RUN/val.json                         validation success of every scheduled checkpoint and the best one
    RUN/held_out.json                    checks of the agent while it trained (the language lesson's) and the best
                                         step, whose scheduled checkpoint is kept
    RUN/eval/TASK-MODE-CKPT.json         evaluation results (cliport-eval); RUN/eval/tensorboard/ their events
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import Any

CONFIG = "config.json"
METRICS = "metrics.csv"
MODEL_WEIGHTS = "model.safetensors"
TENSORBOARD = "tensorboard"
TENSORBOARD_VAL = "val"
CHECKPOINTS = "checkpoints"
LAST = "last"
VAL = "val.json"
HELD_OUT = "held_out.json"
EVAL = "eval"
_STEP_FILE = re.compile(r"step-(\d{6})\.pt")


@dataclass(frozen=True)
class RunDir:
    """Paths inside one run folder."""

    root: str

    @property
    def config(self) -> str:
        return os.path.join(self.root, CONFIG)

    @property
    def metrics(self) -> str:
        return os.path.join(self.root, METRICS)

    @property
    def tensorboard(self) -> str:
        return os.path.join(self.root, TENSORBOARD)

    @property
    def tensorboard_val(self) -> str:
        """Validation's events: a folder of their own, as another process writes them during training."""
        return os.path.join(self.root, TENSORBOARD, TENSORBOARD_VAL)

    @property
    def model_weights(self) -> str:
        """``RUN/model.safetensors``: the newest scheduled checkpoint's trainable weights."""
        return os.path.join(self.root, MODEL_WEIGHTS)

    @property
    def val(self) -> str:
        return os.path.join(self.root, VAL)

    @property
    def held_out(self) -> str:
        """``RUN/held_out.json``: the checks made while training (:mod:`cliport.train.checks`)."""
        return os.path.join(self.root, HELD_OUT)

    @property
    def eval_dir(self) -> str:
        return os.path.join(self.root, EVAL)

    def checkpoint(self, step: int | str) -> str:
        """``checkpoints/step-NNNNNN.pt`` of a step, or ``checkpoints/last.pt`` for ``"last"``."""
        name = f"{LAST}.pt" if step == LAST else f"step-{int(step):06d}.pt"
        return os.path.join(self.root, CHECKPOINTS, name)

    def weights(self, step: int) -> str:
        """``checkpoints/step-NNNNNN.safetensors``: a scheduled checkpoint's trainable weights as safetensors."""
        return os.path.join(self.root, CHECKPOINTS, f"step-{int(step):06d}.safetensors")

    def checkpoint_steps(self) -> list[int]:
        """Steps of the scheduled checkpoints present, sorted."""
        folder = os.path.join(self.root, CHECKPOINTS)
        if not os.path.isdir(folder):
            return []
        return sorted(int(m.group(1)) for f in os.listdir(folder) if (m := _STEP_FILE.fullmatch(f)))

    def resolve(self, which: str, val_step: int | None = None, allow_all: bool = True) -> list[int | str]:
        """The checkpoints ``which`` names: ``"best"`` (``val_step``, the step val.json chose, or the only
        scheduled checkpoint of a run without validation results), ``"last"``,
        ``"all"`` (every scheduled one, where allowed) or one saved step; RunDirError / ConfigError naming
        the problem."""
        from cliport.errors import ConfigError, RunDirError

        if not os.path.isdir(self.root):
            raise RunDirError(f"run folder not found: {self.root}")
        steps = self.checkpoint_steps()
        if not steps and not os.path.exists(self.checkpoint(LAST)):
            raise RunDirError(f"no checkpoints in {os.path.join(self.root, CHECKPOINTS)}")
        if which == "all" and allow_all:
            return list(steps)
        if which == LAST:
            return [LAST]
        if which == "best":
            if val_step is None and len(steps) == 1:  # e.g. a converted reference checkpoint
                return [steps[0]]
            if val_step is None:
                raise RunDirError(
                    f"no validation results in {self.root} ({VAL}) to pick the best checkpoint: use "
                    "--checkpoint last|STEP, or train with --val-episodes > 0"
                )
            return [val_step]
        if not which.isdigit() or int(which) not in steps:
            choices = "best, last, all" if allow_all else "best, last"
            raise ConfigError(f"--checkpoint must be {choices} or one of the saved steps {steps}, got {which!r}")
        return [int(which)]

    def best_step(self) -> int | None:
        """The step val.json chose, else the step the checks made while training chose (held_out.json), or None
        without either."""
        from cliport.utils.files import read_json

        if os.path.exists(self.val):
            return int(read_json(self.val)["best_step"])
        if os.path.exists(self.held_out):
            step = read_json(self.held_out).get("best_step")
            return None if step is None else int(step)
        return None

    def is_run(self) -> bool:
        """Whether the folder holds a run (its resolved config)."""
        return os.path.isfile(self.config)

    def has_progress(self) -> bool:
        """Whether training saved anything a resume could continue from."""
        return os.path.exists(self.checkpoint(LAST)) or bool(self.checkpoint_steps())


def load_resume_state(path: str) -> dict[str, Any]:
    """The trainer state saved in a run's ``checkpoints/last.pt`` (step, optimiser, RNG, seconds trained);
    TrainError if the file holds none."""
    from cliport.errors import TrainError
    from cliport.utils.files import load_torch

    payload = load_torch(path)
    if "trainer" not in payload:
        raise TrainError(f"{path} holds no trainer state")
    return payload["trainer"]
