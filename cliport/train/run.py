"""A training run's set-up and the state its steps share (:class:`TrainRun`): the processes (DDP under torchrun),
the run folder, the device and seed, the agent with its recipe's optimiser, and the demonstrations it learns from.

:func:`set_up` is the first step of :func:`cliport.train.trainer.train`; resuming (:mod:`cliport.train.resume`),
the step loop (:mod:`cliport.train.step_loop`) and saving and logging (:mod:`cliport.train.saving`) read and move
the state it returns.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
import torch.distributed as dist

from cliport.env.config import expected_renderer
from cliport.errors import TrainError
from cliport.train.checks import AgentCheck
from cliport.train.config import TrainConfig
from cliport.train.lr_schedule import LrCooldown
from cliport.train.recipes import Recipe
from cliport.utils.device import resolve_device
from cliport.utils.run_dir import RunDir

if TYPE_CHECKING:
    from cliport.agents.base import PickPlaceAgent
    from cliport.data.dataset import DemoDataset


@dataclass
class TrainRun:
    """What the steps of one training process share: its config and place among the processes, the run folder,
    the agent, optimiser and demonstrations, and how far training has got (``step``, seconds trained by earlier
    attempts, nets drawn again at the start)."""

    config: TrainConfig
    rank: int
    world: int
    local_rank: int
    folder: RunDir
    device: torch.device
    recipe: Recipe
    agent: PickPlaceAgent
    optimizer: torch.optim.Optimizer
    cooldown: LrCooldown
    dataset: DemoDataset
    step: int = 0
    #: Seconds of training loop in earlier attempts of this run (from its last.pt).
    trained_before: float = 0.0
    #: Nets drawn again at the start (:mod:`cliport.train.live_start`); recorded in every checkpoint.
    init_draws: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: ``time.perf_counter()`` when this attempt's training loop began (:meth:`start_clock`).
    loop_start: float = 0.0

    def note(self, message: str) -> None:
        """Print ``note: message`` on stderr, once (from the first process)."""
        note(self.rank, message)

    def start_clock(self) -> None:
        """The training loop (its checks and saves included) begins now."""
        self.loop_start = time.perf_counter()

    def trained_s(self) -> float:
        """Seconds of training loop so far, earlier attempts included."""
        return self.trained_before + time.perf_counter() - self.loop_start

    def out_of_time(self) -> bool:
        """Whether the run's ``time_budget_s`` (if any) is spent."""
        return self.config.time_budget_s > 0 and self.trained_s() >= self.config.time_budget_s

    def finished(self) -> bool:
        """Whether the run has trained its last step: ``n_steps``, or its time budget is spent."""
        return self.step == self.config.n_steps or self.out_of_time()

    def fraction(self) -> float:
        """How far the run has got, 0 to 1: of its steps, or of its time budget where that is further."""
        done = self.step / self.config.n_steps
        budget = self.config.time_budget_s
        return max(done, self.trained_s() / budget) if budget > 0 else done


def set_up(config: TrainConfig, resume: bool, check: AgentCheck | None = None) -> TrainRun:
    """The set-up of a run: processes, run folder (checked: ``resume`` needs a run, a fresh start needs a folder
    without progress), device, seed, agent, recipe and optimiser, demonstrations (checked against validation's
    rendering) and, for agents that centre their sentence features, the centring fitted to the demos'
    instructions. TrainError for a run that cannot start as asked."""
    from cliport.agents import make_agent
    from cliport.data.dataset import DemoDataset

    rank, world, local_rank = _distributed()
    folder = _check_start(config, resume)
    if world > 1:
        dist.barrier()  # every rank has checked the run folder before rank 0 writes into it
    device = resolve_device(config.device)
    if device.type == "cuda" and world > 1:
        device = torch.device("cuda", local_rank)
    torch.manual_seed(config.seed * 1000 + rank)

    recipe = config.training_recipe()
    agent = make_agent(config.agent, config.agent_config).to(device)
    optimizer, applied = recipe.prepare(agent)
    cooldown = LrCooldown(optimizer, config.lr_cooldown)  # before a resume loads the cooled rates
    if recipe.encoder_norms == "train" and not applied and agent.encoder is not None and agent.encoder.norm_stats():
        note(
            rank,
            f"the {recipe.name} recipe trains the frozen encoder's batch norms per net, but {agent.name} keeps no "
            "per-net statistics: its encoder stays in inference mode",
        )
    dataset = DemoDataset(
        config.data_dir,
        config.task,
        "train",
        config.n_demos,
        seed=config.seed,
        rotation_aug=config.rotation_aug,
        aug_pivot=recipe.aug_pivot,
        aug_interpolation=recipe.aug_interpolation,
        every_instruction=config.every_instruction,
    )
    _check_demo_rendering(dataset, config)
    if agent.centers_sentences:
        fitted = agent.fit_sentence_centering(dataset.instructions())
        if rank == 0:
            print(
                f"sentence features centred on the training set's {fitted['instructions']} instructions "
                f"(scale {fitted['scale']:.2f})",
                file=sys.stderr,
            )
    if agent.phrase_bank is not None:
        assert agent.encoder is not None
        held = agent.phrase_bank.fit(agent.encoder, dataset.instructions())
        if rank == 0:
            print(f"similarity maps against a bank of the training set's {held} phrases", file=sys.stderr)
    if check is not None and world > 1:
        raise TrainError("checks of the training agent run in a single process, not under DDP")
    return TrainRun(config, rank, world, local_rank, folder, device, recipe, agent, optimizer, cooldown, dataset)


def note(rank: int, message: str) -> None:
    """Print ``note: message`` on stderr from the first process (``rank`` 0) only."""
    if rank == 0:
        print(f"note: {message}", file=sys.stderr)


def _distributed() -> tuple[int, int, int]:
    """(rank, world size, local rank); initialises the process group under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, 0
    if not dist.is_initialized():
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if torch.cuda.is_available():
        torch.cuda.set_device(local)
    return dist.get_rank(), world, local


def _check_start(config: TrainConfig, resume: bool) -> RunDir:
    """The run folder, if the run can start there as asked; TrainError naming the problem otherwise."""
    run = RunDir(config.resolved_run_dir())
    if resume:
        if not run.is_run():
            raise TrainError(f"nothing to resume in {run.root}: it holds no run (no config.json)")
        return run
    if run.is_run():
        if run.has_progress():
            raise TrainError(
                f"run folder {run.root} already holds a run: pass --resume to continue it, or choose --run-dir"
            )
        # A run that died before its first save has nothing to lose: start it again from scratch.
    return run


def _check_demo_rendering(dataset: DemoDataset, config: TrainConfig) -> None:
    """Validation must render as the demos were rendered: same camera scale, same renderer."""
    if config.val_episodes == 0:
        return
    for task, scale in dataset.recorded_camera_scales().items():
        if scale is not None and abs(scale - config.env.camera_scale) > 1e-9:
            raise TrainError(
                f"the {task} demos were rendered at camera_scale {scale} but validation would render at "
                f"{config.env.camera_scale}: pass --camera-scale {scale}"
            )
    validation = expected_renderer(config.env.renderer)
    for task, renderer in dataset.recorded_renderers().items():
        if renderer is not None and renderer != validation:
            flag = "cpu" if renderer == "tiny" else "egl"
            raise TrainError(
                f"the {task} demos were rendered with {renderer} but validation would render with {validation} "
                f"(renderer {config.env.renderer!r} on this machine): pass --renderer {flag}"
            )
