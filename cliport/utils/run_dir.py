"""The layout of a training run folder, in one place for training, evaluation, the study and the CLIs.

::

    RUN/config.json                      the resolved train config (agent, env and validation settings)
    RUN/metrics.csv                      step, losses, throughput (RUN/tensorboard/ when tensorboard is installed)
    RUN/checkpoints/step-001000.pt ...   scheduled checkpoints (agent weights + config + weight sources)
    RUN/checkpoints/last.pt              rolling resume point (also optimiser, step and RNG state)
    RUN/val.json                         validation success of every scheduled checkpoint and the best one
    RUN/eval/TASK-MODE-CKPT.json         evaluation results (cliport-eval)
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

CONFIG = "config.json"
METRICS = "metrics.csv"
TENSORBOARD = "tensorboard"
CHECKPOINTS = "checkpoints"
LAST = "last"
VAL = "val.json"
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
    def val(self) -> str:
        return os.path.join(self.root, VAL)

    @property
    def eval_dir(self) -> str:
        return os.path.join(self.root, EVAL)

    def checkpoint(self, step: int | str) -> str:
        """``checkpoints/step-NNNNNN.pt`` of a step, or ``checkpoints/last.pt`` for ``"last"``."""
        name = f"{LAST}.pt" if step == LAST else f"step-{int(step):06d}.pt"
        return os.path.join(self.root, CHECKPOINTS, name)

    def checkpoint_steps(self) -> list[int]:
        """Steps of the scheduled checkpoints present, sorted."""
        folder = os.path.join(self.root, CHECKPOINTS)
        if not os.path.isdir(folder):
            return []
        return sorted(int(m.group(1)) for f in os.listdir(folder) if (m := _STEP_FILE.fullmatch(f)))

    def is_run(self) -> bool:
        """Whether the folder holds a run (its resolved config)."""
        return os.path.isfile(self.config)

    def has_progress(self) -> bool:
        """Whether training saved anything a resume could continue from."""
        return os.path.exists(self.checkpoint(LAST)) or bool(self.checkpoint_steps())
