"""The defaults a run takes where its command is given none: the place rotations its agent trains with and the
renderer setting of its episodes, decided by :func:`run_defaults` for every command (``cliport-train``,
``cliport-reproduce``, ``cliport-eval``, ``scripts/quickstart.py`` and the notebooks). A command that departs from
them on purpose says so by an argument (``papers_protocol``). Nothing here imports torch, an agent or the
simulator: the console scripts resolve their configs without them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from cliport.env.config import check_renderer
from cliport.utils.config import merge, read_defaults

if TYPE_CHECKING:
    from cliport.train.config import TrainConfig


@dataclass(frozen=True)
class RunDefaults:
    """What :func:`run_defaults` decided for one run.

    Args:
        n_rotations: the place rotations the agent trains with; None: the agent config's count
            (``configs/<agent>.toml``: the papers' 36).
        renderer: the renderer setting of the run's episodes: auto, egl or cpu
            (:func:`cliport.env.config.renderer_choice` says what it means on a machine).
        note: the line the command prints on stderr about a place-rotation default that is not the agent's count,
            or that keeps the agent's count where one rotation would do; None: nothing to say.
    """

    n_rotations: int | None
    renderer: str
    note: str | None = None

    def overrides(self) -> dict[str, Any]:
        """The defaults as train config overrides (``TrainConfig.build``'s nested layout)."""
        rotations = {} if self.n_rotations is None else {"n_rotations": self.n_rotations}
        return {"agent_config": rotations, "env": {"renderer": self.renderer}}


def run_defaults(
    task: str,
    *,
    n_rotations: int | None = None,
    renderer: str | None = None,
    saved: TrainConfig | None = None,
    papers_protocol: bool = False,
) -> RunDefaults:
    """The place rotations and the renderer setting of a run of ``task`` (a task or a multi-task group).

    Place rotations: ``n_rotations`` where given (``--n-rotations``); else ``saved``'s, the count a trained run
    trained with (``cliport-eval``: its checkpoints keep it); else one rotation where the task's expert place yaw
    carries no information (round bowls: nothing checks it, so one query crop per sample does;
    ``Task.place_yaw_informative``), else None: the agent config's count (the papers' 36). ``papers_protocol``
    keeps the agent config's count on every task, round bowls too: ``cliport-reproduce`` passes it so that its
    cells train as the papers did and compare with their published columns, and its note says so.

    Renderer: ``renderer`` where given (``--renderer``); else ``saved``'s (``cliport-eval`` renders as the run's
    demos and validation did); else the workcell's default (``configs/env.toml``'s auto, or an ``[env]`` table's
    in ``configs/train.toml``, as a train config resolves it). ConfigError unless auto, egl or cpu.
    """
    if renderer is not None:
        check_renderer(renderer, "--renderer")
    else:
        renderer = saved.env.renderer if saved is not None else _workcell_renderer()
    if n_rotations is not None:
        return RunDefaults(n_rotations, renderer)
    if saved is not None:
        return RunDefaults(saved.agent_config.n_rotations, renderer)
    from cliport import tasks

    if tasks.place_yaw_informative(task):
        return RunDefaults(None, renderer)
    uninformative = f"note: the place yaw of {task} carries no information (nothing checks it)"
    if papers_protocol:
        note = (
            f"{uninformative}, but the papers' protocol keeps the agent's 36 place rotations so that the study's "
            "cells compare with the published columns; pass --n-rotations 1 for one query crop per sample"
        )
        return RunDefaults(None, renderer, note)
    note = (
        f"{uninformative}, so the agent trains with one place rotation (one query crop per sample); pass "
        "--n-rotations to choose another count"
    )
    return RunDefaults(1, renderer, note)


def _workcell_renderer() -> str:
    """The renderer setting a train config takes by default: ``configs/env.toml``'s under ``configs/train.toml``'s
    ``[env]`` table, where it has one."""
    return str(merge(read_defaults("env"), read_defaults("train").get("env", {}))["renderer"])
