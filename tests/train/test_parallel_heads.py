"""parallel_heads: on the CPU a step differentiates the pick and place halves of the loss at once, in two threads.
The halves share no parameter, so with the same per-op thread count the step trains exactly as one backward."""

from __future__ import annotations

import gc
import threading

import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent
from cliport.train.graphed_step import TrainStep
from cliport.train.recipes import get_recipe

H, W = 64, 32


def _batch(seed: int) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {
        "color": torch.randint(0, 255, (1, H, W, 3), dtype=torch.uint8, generator=g),
        "height": torch.rand(1, H, W, generator=g) * 0.05,
        "pick_pix": torch.randint(0, W, (1, 2), generator=g),
        "place_pix": torch.randint(0, W, (1, 2), generator=g),
        "place_rot": torch.randint(0, 4, (1,), generator=g),
        "lang": ["put the red block in the green bowl" if seed % 2 else "put the blue block in the red bowl"],
    }


@pytest.fixture
def threads():
    """Restore the process's intra-op thread count after the test."""
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def _train(name: str, recipe: str, parallel: bool, tiny_config, n: int = 3) -> tuple[PickPlaceAgent, list, TrainStep]:
    torch.manual_seed(0)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    agent = make_agent(name, tiny_config(name, n_rotations=4))
    if agent.uses_language:  # the frozen text encoder's features (cached) on one thread in both runs
        agent.sentence_features(sorted({text for seed in range(n) for text in _batch(seed)["lang"]}))
    torch.set_num_threads(threads)
    optimizer, _ = get_recipe(recipe).prepare(agent)
    terms: list[torch.Tensor] = []
    step = TrainStep(
        agent, optimizer, get_recipe(recipe).loss, observers=(terms.append,), graphs=False, parallel_heads=parallel
    )
    for seed in range(n):
        step(_batch(seed))
    return agent, terms, step


@pytest.mark.parametrize(("name", "recipe"), [("two_stream", "ravens"), ("transporter_only", "cliport")])
def test_the_halves_at_once_train_as_one_backward(name: str, recipe: str, tiny_config, threads) -> None:
    """Two intra-op threads split one per half against one thread for the joint backward: the same kernels, so
    the same losses and weights bit for bit (the cliport recipe: the cell-averaged loss, each half scaled). The
    sentence features, computed outside the halves, are computed on one thread in both."""
    torch.set_num_threads(1)
    joint, joint_terms, joint_step = _train(name, recipe, False, tiny_config)
    torch.set_num_threads(2)
    halves, halves_terms, halves_step = _train(name, recipe, True, tiny_config)
    assert halves_step.parallel_heads and not joint_step.parallel_heads
    assert torch.get_num_threads() == 2  # the step gives the process its thread count back
    assert torch.equal(torch.stack(joint_terms), torch.stack(halves_terms))
    trained = halves.trainable_state_dict()
    for key, value in joint.trainable_state_dict().items():
        assert torch.equal(value, trained[key]), key


def test_an_error_in_the_place_half_is_raised_by_the_step(tiny_config, threads, monkeypatch) -> None:
    torch.set_num_threads(2)
    agent = make_agent("transporter_only", tiny_config("transporter_only", n_rotations=4))
    step = TrainStep(agent, agent.make_optimizer(), graphs=False, parallel_heads=True)

    def broken(*args, **kwargs):
        raise RuntimeError("the place half failed")

    monkeypatch.setattr(agent, "_place_loss_terms", broken)
    with pytest.raises(RuntimeError, match="the place half failed"):
        step(_batch(0))
    assert torch.get_num_threads() == 2


def test_parallel_heads_apply_to_plain_cpu_steps_only(tiny_config) -> None:
    agent = make_agent("transporter_only", tiny_config("transporter_only", n_rotations=4))
    optimizer = agent.make_optimizer()
    assert TrainStep(agent, optimizer, graphs=False, parallel_heads=True).parallel_heads
    assert not TrainStep(
        agent, optimizer, graphs=False, parallel_heads=True, autocast_dtype=torch.bfloat16
    ).parallel_heads
    assert not TrainStep(agent, optimizer, graphs=False, parallel_heads=False).parallel_heads


def test_the_place_thread_ends_with_its_step(tiny_config, threads) -> None:
    torch.set_num_threads(2)
    agent = make_agent("transporter_only", tiny_config("transporter_only", n_rotations=4))
    step = TrainStep(agent, agent.make_optimizer(), graphs=False, parallel_heads=True)
    before = set(threading.enumerate())
    step(_batch(0))
    [thread] = [t for t in set(threading.enumerate()) - before if t.name.startswith("place-head")]
    del step
    gc.collect()
    thread.join(timeout=10)
    assert not thread.is_alive()
