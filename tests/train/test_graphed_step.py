"""The captured training step's bookkeeping, on the CPU: static buffers, warm-up, capture, replay, a changed
shape, re-allocated weights, a failed capture, the trainer's switch, and what a capture forbids.

CUDA graphs need a GPU, so ``graphed_step.capture`` is replaced here by a double with a captured graph's
semantics: nothing runs at capture; every replay reads the static inputs, writes the gradients afresh and
steps Adam. Replays then run the eager kernels on the CPU, so they must give the eager step's results bit
for bit: any input not copied into its buffer, or copied wrongly, shows. The real capture is tested in
tests/agents/test_cuda_speed.py.
"""

from __future__ import annotations

import logging
import math
import os

import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent
from cliport.models.encoders import base as encoders_base
from cliport.train import graphed_step
from cliport.train.config import TrainConfig
from cliport.train.graphed_step import WARMUP_STEPS, TrainStep
from cliport.train.recipes import get_recipe
from cliport.train.trainer import train
from cliport.utils.files import load_torch
from cliport.utils.run_dir import RunDir

H, W = 64, 32
SENTENCES = ["put the red block in the green bowl", "pack the blue box", "stack the yellow blocks"]


class _Replay:
    """An eager stand-in for a captured training step."""

    def __init__(self, body, step: TrainStep) -> None:
        self.body, self.step = body, step

    def replay(self) -> None:
        self.step.optimizer.zero_grad(set_to_none=True)  # a replay writes the gradients, never adds to them
        self.body()


@pytest.fixture
def fake_capture(monkeypatch: pytest.MonkeyPatch) -> list:
    """Let the CPU capture, with :class:`_Replay` as the graph; yields the list of captures made."""
    made: list = []
    steps: list[TrainStep] = []
    real_init = TrainStep.__init__

    def init(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        steps.append(self)

    def capture(body, device, stream):
        graph = _Replay(body, steps[-1])
        made.append(graph)
        return graph

    monkeypatch.setattr(TrainStep, "__init__", init)
    monkeypatch.setattr(graphed_step, "CAPTURE_DEVICES", {"cuda", "cpu"})
    monkeypatch.setattr(graphed_step, "capture", capture)
    return made


def _batch(seed: int, b: int = 1, language: bool = False) -> dict:
    g = torch.Generator().manual_seed(seed)
    batch = {
        "color": torch.randint(0, 255, (b, H, W, 3), dtype=torch.uint8, generator=g),
        "height": torch.rand(b, H, W, generator=g) * 0.05,
        "pick_pix": torch.stack([torch.randint(0, H, (b,), generator=g), torch.randint(0, W, (b,), generator=g)], 1),
        "place_pix": torch.stack([torch.randint(0, H, (b,), generator=g), torch.randint(0, W, (b,), generator=g)], 1),
        "place_rot": torch.randint(0, 4, (b,), generator=g),
    }
    if language:
        batch["lang"] = [SENTENCES[(seed + i) % len(SENTENCES)] for i in range(b)]
    return batch


def _stepper(name: str, recipe: str, graphs: bool, tiny_config) -> tuple[PickPlaceAgent, TrainStep, list]:
    torch.manual_seed(0)
    per_net = {"per_net_clip_stats": True} if recipe == "cliport" and name != "transporter_only" else {}
    agent = make_agent(name, tiny_config(name, n_rotations=4, **per_net))
    optimizer, _ = get_recipe(recipe).prepare(agent)
    terms: list[torch.Tensor] = []
    step = TrainStep(
        agent, optimizer, get_recipe(recipe).loss, observers=(lambda t: terms.append(t.clone()),), graphs=graphs
    )
    return agent, step, terms


def _same_training(a: tuple, b: tuple) -> None:
    (agent_a, _, terms_a), (agent_b, _, terms_b) = a, b
    assert torch.equal(torch.stack(terms_a), torch.stack(terms_b))
    state_a, state_b = agent_a.state_dict(), agent_b.state_dict()
    for key, value in state_a.items():
        assert torch.equal(value, state_b[key]), key


@pytest.mark.parametrize(
    ("name", "recipe"),
    [("transporter_only", "ravens"), ("two_stream", "cliport")],
    ids=["transporter-ravens", "two-stream-cliport"],
)
def test_replayed_steps_equal_eager_steps(name: str, recipe: str, fake_capture, tiny_config) -> None:
    """Three warm-up steps, a capture, then replays on new batches (other images, targets and sentences) train
    exactly as eager steps do; with the cliport recipe the per-net CLIP batch-norm statistics too."""
    language = name == "two_stream"
    eager = _stepper(name, recipe, False, tiny_config)
    graphed = _stepper(name, recipe, True, tiny_config)
    if recipe == "cliport":
        assert any(getattr(m, "train_encoder_norms", False) for m in graphed[0].modules())
    stats_before = {k: v.clone() for k, v in graphed[0].state_dict().items() if "encoder_stats" in k}
    n = WARMUP_STEPS + 2
    for seed in range(n):
        eager[1](_batch(seed, language=language))
        graphed[1](_batch(seed, language=language))
    step = graphed[1]
    assert step.captured and len(fake_capture) == 1
    assert (step.eager_steps, step.replays) == (WARMUP_STEPS, n - WARMUP_STEPS)
    assert eager[1].eager_steps == n and not eager[1].captured
    _same_training(eager, graphed)
    if recipe == "cliport":
        moved = [
            k
            for k, v in graphed[0].state_dict().items()
            if "encoder_stats" in k and not torch.equal(v, stats_before[k])
        ]
        assert moved, "the per-net CLIP statistics did not train"


def test_a_changed_shape_steps_eagerly_and_the_graph_serves_the_next_step(fake_capture, tiny_config) -> None:
    eager = _stepper("transporter_only", "ravens", False, tiny_config)
    graphed = _stepper("transporter_only", "ravens", True, tiny_config)
    sizes = [1] * (WARMUP_STEPS + 1) + [2, 1, 2, 1]
    for seed, b in enumerate(sizes):
        eager[1](_batch(seed, b))
        graphed[1](_batch(seed, b))
    step = graphed[1]
    assert step.replays == 3 and step.eager_steps == WARMUP_STEPS + 2 and len(fake_capture) == 1
    _same_training(eager, graphed)


def test_reallocated_weights_are_captured_again(fake_capture, tiny_config) -> None:
    agent, step, _ = _stepper("transporter_only", "ravens", True, tiny_config)
    for seed in range(WARMUP_STEPS + 1):
        step(_batch(seed))
    assert step.captured and len(fake_capture) == 1
    agent.load_state_dict({k: v.clone() for k, v in agent.state_dict().items()}, assign=True)
    step(_batch(10))  # new tensors: the old graph would read freed memory; this step warms up again
    assert not step.captured and step.eager_steps == WARMUP_STEPS + 1
    for seed in range(11, 11 + WARMUP_STEPS):
        step(_batch(seed))
    assert step.captured and len(fake_capture) == 2


def test_a_failed_capture_trains_eagerly_with_one_warning(monkeypatch, fake_capture, tiny_config, caplog) -> None:
    def refuse(body, device, stream):
        raise RuntimeError("operation not permitted when stream is capturing")

    monkeypatch.setattr(graphed_step, "capture", refuse)
    eager = _stepper("transporter_only", "ravens", False, tiny_config)
    graphed = _stepper("transporter_only", "ravens", True, tiny_config)
    with caplog.at_level(logging.WARNING, logger="cliport.train.graphed_step"):
        for seed in range(WARMUP_STEPS + 4):
            eager[1](_batch(seed))
            graphed[1](_batch(seed))
    assert [r.getMessage() for r in caplog.records if "training eagerly" in r.getMessage()] == [
        "capturing the training step as a CUDA graph failed (RuntimeError: operation not permitted when stream is "
        "capturing); training eagerly from now on"
    ]
    assert graphed[1].failed and graphed[1].replays == 0 and not graphed[1].captured
    _same_training(eager, graphed)


def test_a_wrapped_model_refuses_graphs(tiny_config) -> None:
    agent = make_agent("transporter_only", tiny_config("transporter_only", n_rotations=4))
    with pytest.raises(ValueError, match="DDP"):
        TrainStep(agent, agent.make_optimizer(), model=lambda batch: None, graphs=True)


# ------------------------------------------------------------------ what a CUDA graph capture forbids


class _HostAccess(AssertionError):
    pass


def _refuse(what: str):
    def refuse(*args, **kwargs):
        raise _HostAccess(f"{what} inside the captured training step")

    return refuse


@pytest.mark.parametrize(
    ("name", "recipe"),
    [("transporter_only", "ravens"), ("two_stream", "cliport"), ("two_stream", "ravens"), ("clip_only", "cliport")],
)
def test_the_captured_step_neither_reads_the_device_nor_builds_tensors_from_host_data(
    name: str, recipe: str, monkeypatch, tiny_config
) -> None:
    """A CUDA graph capture fails on a synchronisation (``.item()``, ``.tolist()``, a tensor's truth value) or a
    host-to-device copy (a tensor built from Python data) inside the step. Here the capture runs the step once with
    those refused: forward, loss, backward, fused Adam and the loss bookkeeping of the trainer (sums, dead maps)."""
    from cliport.train.dead_maps import DeadMapWatch
    from cliport.train.loss_sums import LossSums

    torch.manual_seed(0)
    per_net = {"per_net_clip_stats": True} if recipe == "cliport" else {}
    agent = make_agent(name, tiny_config(name, n_rotations=4, **per_net))
    optimizer, applied = get_recipe(recipe).prepare(agent)
    assert applied or recipe != "cliport"
    sums, watch = LossSums(), DeadMapWatch()
    monkeypatch.setattr(graphed_step, "CAPTURE_DEVICES", {"cpu"})
    monkeypatch.setattr(encoders_base, "RECENT_IMAGE_DEVICES", set())  # as on CUDA: no image comparisons
    step = TrainStep(agent, optimizer, get_recipe(recipe).loss, observers=(sums.add, watch.observe), graphs=True)
    captured: list[bool] = []

    def strict_capture(body, device, stream):
        with monkeypatch.context() as m:
            for attr in ("tensor", "as_tensor", "from_numpy"):
                real = getattr(torch, attr)
                guard = _refuse(f"torch.{attr} of host data")
                m.setattr(
                    torch,
                    attr,
                    lambda data, *a, _real=real, _guard=guard, **k: (
                        _real(data, *a, **k) if isinstance(data, torch.Tensor) else _guard()
                    ),
                )
            for method in ("item", "tolist", "numpy", "__bool__", "__float__", "__int__", "__index__"):
                m.setattr(torch.Tensor, method, _refuse(f"Tensor.{method}"))
            body()
        captured.append(True)
        return _Replay(body, step)

    monkeypatch.setattr(graphed_step, "capture", strict_capture)
    language = agent.uses_language
    for seed in range(WARMUP_STEPS + 1):
        step(_batch(seed, language=language))
    assert step.failed is None and captured == [True] and step.captured, step.failed


# ------------------------------------------------------------------ the trainer


def _config(tmp_path, name: str, n_steps: int, tiny_config, **overrides) -> TrainConfig:
    base = {
        "agent": "transporter_only", "task": "place-red-in-green", "n_demos": 2, "n_steps": n_steps, "batch_size": 1,
        "data_dir": str(tmp_path), "run_dir": str(tmp_path / name), "device": "cpu", "num_workers": 0,
        "val_episodes": 0, "checkpoint_steps": [n_steps], "checkpoint_every": 0, "log_every": 1,
        "save_last_every": 3, "agent_config": tiny_config("transporter_only", n_rotations=4),
    }  # fmt: skip
    return TrainConfig.build({**base, **overrides})


def _losses(run_dir) -> list[list[float]]:
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        rows = f.read().split()[1:]
    return [[float(v) for v in row.split(",")[1:4]] for row in rows]


def test_the_trainer_replays_and_resumes_as_it_trains_eagerly(
    tmp_path, make_synthetic_dataset, fake_capture, tiny_config
) -> None:
    """cliport-train with the captured step (the double) writes the losses and weights of --no-train-graphs over a
    run stopped after 4 steps and resumed: each of its processes warms up, captures and replays."""
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    n = 2 * (WARMUP_STEPS + 1)
    for name, graphs in (("eager", False), ("graphed", True)):
        train(_config(tmp_path, name, n // 2, tiny_config, train_graphs=graphs), progress=False)
        train(_config(tmp_path, name, n, tiny_config, train_graphs=graphs), resume=True, progress=False)
    assert len(fake_capture) == 2  # one in each process of the graphed run
    eager = _losses(tmp_path / "eager")
    assert len(eager) == n and all(math.isfinite(v) for row in eager for v in row)
    assert _losses(tmp_path / "graphed") == eager
    runs = [RunDir(str(tmp_path / kind)) for kind in ("eager", "graphed")]
    weights = [load_torch(r.checkpoint(n))["state_dict"] for r in runs]
    for key, value in weights[0].items():
        assert torch.equal(value, weights[1][key]), key


def test_no_train_graphs_flag_reaches_the_config(tmp_path) -> None:
    from cliport.cli.train import _parser, config_from_args

    parser, dests = _parser()
    for flags, expected in (([], True), (["--no-train-graphs"], False), (["--train-graphs"], True)):
        args = parser.parse_args(["--task", "place-red-in-green", *flags])
        config = config_from_args(args, dests)
        assert config.train_graphs is expected and config.compile is False
    saved = {**config.to_dict()}
    del saved["train_graphs"], saved["compile"]  # a run saved before these settings existed
    old = TrainConfig.from_saved(saved)
    assert old.train_graphs is True and old.compile is False
