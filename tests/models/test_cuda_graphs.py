"""The graph bookkeeping of GraphedForward, on the CPU: padded batch sizes, static buffers, invalidation,
inference mode, threads, the eager fallback and release without the cycle collector.

CUDA graphs need a GPU, so ``cuda_graphs.capture`` is replaced here by a double with the same buffer
semantics: replay reads the static inputs and overwrites the static output, and it refuses to replay
after the owner's parameters moved (a real graph would silently read freed memory). The real capture is
tested in tests/agents/test_cuda_speed.py.
"""

from __future__ import annotations

import contextlib
import copy
import gc
import logging
import threading
import time
import weakref
from collections.abc import Iterator

import numpy as np
import pytest
import torch
from torch import nn

from cliport.agents import make_agent
from cliport.models import cuda_graphs
from cliport.models.cuda_graphs import BATCH_SIZES, GraphedForward, GraphMemory


class _ReplayGraph:
    """An eager stand-in for a captured CUDA graph; like one, it holds no reference to the module."""

    def __init__(self, fn, inputs, output) -> None:
        owner = getattr(fn, "__self__", None)
        self.fn = weakref.WeakMethod(fn) if owner is not None else (lambda: fn)
        self.inputs, self.output = inputs, output
        self.owner = weakref.ref(owner) if isinstance(owner, nn.Module) else None
        self.addresses = cuda_graphs._tensor_fingerprint(owner) if self.owner is not None else None

    def replay(self) -> None:
        if self.owner is not None:
            assert cuda_graphs._tensor_fingerprint(self.owner()) == self.addresses, "replayed a stale graph"
        time.sleep(0.002)  # widen the window in which an unlocked second caller would overwrite the inputs
        self.output.copy_(self.fn()(*self.inputs))


@pytest.fixture
def fake_capture(monkeypatch: pytest.MonkeyPatch) -> Iterator[list]:
    """Replace the CUDA capture by :class:`_ReplayGraph`; yields the list of captures made."""
    made: list[_ReplayGraph] = []

    def capture(fn, inputs, memory):
        output = fn(*inputs)
        graph = _ReplayGraph(fn, inputs, output)
        made.append(graph)
        return graph, output

    monkeypatch.setattr(cuda_graphs, "capture", capture)
    yield made


class PerSample(nn.Module):
    """A small per-sample net with a graphed forward over (image (B, 2, 8, 8), code (B, 4))."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(2, 3, 3, padding=1)
        self.mix = nn.Linear(4, 3)
        self.graphs = GraphedForward(self.forward)

    def forward(self, image: torch.Tensor, code: torch.Tensor | None) -> torch.Tensor:
        """(B, 2, 8, 8), (B, 4) or None -> (B, 3, 8, 8)."""
        out = self.conv(image)
        return out if code is None else out * self.mix(code)[:, :, None, None]


def _inputs(b: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, 2, 8, 8, generator=g), torch.randn(b, 4, generator=g)


@torch.no_grad()
def test_batches_are_padded_to_few_sizes_and_each_sample_is_its_own(fake_capture) -> None:
    torch.manual_seed(0)
    net = PerSample()
    for b in [1, 2, 3, 5, 8, 7, 6, 4, 11, 17]:  # what an engine with up to 17 workers might hand in
        image, code = _inputs(b, seed=b)
        got = net.graphs(image, code)
        assert got.shape == (b, 3, 8, 8)
        torch.testing.assert_close(got, net(image, code), rtol=0, atol=1e-6)
    assert net.graphs.captured_batch_sizes() == list(BATCH_SIZES)  # 11 and 17 ran in chunks of 8
    assert len(fake_capture) == len(BATCH_SIZES)
    assert net.graphs.padded_size(3) == 4 and net.graphs.padded_size(9) == 8


@torch.no_grad()
def test_every_call_uses_its_own_inputs_and_gets_its_own_output(fake_capture) -> None:
    torch.manual_seed(0)
    net = PerSample()
    first_inputs, second_inputs = _inputs(3, seed=1), _inputs(3, seed=2)  # different codes per batch entry
    first = net.graphs(*first_inputs)
    second = net.graphs(*second_inputs)  # replays the same graph
    assert len(net.graphs) == 1
    torch.testing.assert_close(second, net(*second_inputs), rtol=0, atol=1e-6)
    torch.testing.assert_close(first, net(*first_inputs), rtol=0, atol=1e-6)  # not overwritten by the replay
    none_code = net.graphs(first_inputs[0], None)  # another signature: its own graph
    torch.testing.assert_close(none_code, net(first_inputs[0], None), rtol=0, atol=1e-6)
    assert len(net.graphs) == 2


def test_weights_changed_after_capture(fake_capture) -> None:
    torch.manual_seed(0)
    net = PerSample()
    inputs = _inputs(2, seed=3)
    with torch.no_grad():
        before = net.graphs(*inputs)
    optimizer = torch.optim.Adam(net.parameters(), lr=0.1)
    net(*inputs).square().mean().backward()
    optimizer.step()  # in place: the graph reads the new values
    with torch.no_grad():
        after_step = net.graphs(*inputs)
        torch.testing.assert_close(after_step, net(*inputs), rtol=0, atol=1e-6)
        assert not torch.allclose(after_step, before)
        assert len(fake_capture) == 1
        other = PerSample().state_dict()
        net.load_state_dict(other)  # copied in place
        torch.testing.assert_close(net.graphs(*inputs), net(*inputs), rtol=0, atol=1e-6)
        assert len(fake_capture) == 1
        net.load_state_dict({k: v.clone() for k, v in other.items()}, assign=True)  # new tensors
        torch.testing.assert_close(net.graphs(*inputs), net(*inputs), rtol=0, atol=1e-6)
        assert len(fake_capture) == 2  # recaptured, the stale graph never replayed
        net.mix = nn.Linear(4, 3)  # a replaced sub-module
        torch.testing.assert_close(net.graphs(*inputs), net(*inputs), rtol=0, atol=1e-6)
        assert len(fake_capture) == 3 and len(net.graphs) == 1


def test_inference_mode_capture_serves_later_calls_outside_it(fake_capture) -> None:
    torch.manual_seed(0)
    net = PerSample()
    inputs = _inputs(2, seed=4)
    with torch.inference_mode():
        first = net.graphs(*inputs)
    with torch.no_grad():
        second = net.graphs(*_inputs(2, seed=5))  # copies into the static inputs: they must be normal tensors
        torch.testing.assert_close(second, net(*_inputs(2, seed=5)), rtol=0, atol=1e-6)
    assert not second.is_inference()
    with torch.inference_mode():
        torch.testing.assert_close(net.graphs(*inputs), first, rtol=0, atol=0)
    assert len(fake_capture) == 1


@torch.no_grad()
def test_concurrent_callers_never_mix_inputs(fake_capture) -> None:
    torch.manual_seed(0)
    net = PerSample()
    jobs = [_inputs(2, seed=10 + i) for i in range(4)]
    expected = [net(*job) for job in jobs]
    net.graphs(*jobs[0])  # capture first, then replay from four threads at once
    failures: list[str] = []

    def caller(i: int) -> None:
        with torch.no_grad():
            for _ in range(15):
                if not torch.allclose(net.graphs(*jobs[i]), expected[i], atol=1e-6):
                    failures.append(f"thread {i} got another caller's result")

    threads = [threading.Thread(target=caller, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert failures == []


@torch.no_grad()
def test_a_failed_capture_falls_back_to_eager_with_one_warning(monkeypatch, caplog) -> None:
    def broken(fn, inputs, memory):
        raise RuntimeError("operation not permitted when stream is capturing")

    monkeypatch.setattr(cuda_graphs, "capture", broken)
    torch.manual_seed(0)
    memory = GraphMemory()
    net = PerSample()
    net.graphs = GraphedForward(net.forward, memory)
    other = GraphedForward(net.conv.forward, memory)  # shares the memory, like an agent's pick and place
    with caplog.at_level(logging.WARNING, logger="cliport.models.cuda_graphs"):
        for b in (1, 3, 9):
            inputs = _inputs(b, seed=b)
            torch.testing.assert_close(net.graphs(*inputs), net(*inputs), rtol=0, atol=0)
            torch.testing.assert_close(other(inputs[0]), net.conv(inputs[0]), rtol=0, atol=0)
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "acting eagerly" in warnings[0] and "stream is capturing" in warnings[0]
    assert memory.failed and len(net.graphs) == 0


def test_a_dropped_module_is_freed_without_the_cycle_collector(fake_capture) -> None:
    gc.disable()
    try:
        net = PerSample()
        with torch.no_grad():
            net.graphs(*_inputs(3, seed=0))
        ref = weakref.ref(net)
        del net
        assert ref() is None
    finally:
        gc.enable()


AGENTS = ["transporter_only", "two_stream"]


@pytest.mark.parametrize("name", AGENTS)
def test_agents_forwards_are_per_sample_when_padded(name: str, fake_capture, tiny_config) -> None:
    """The pick and place forwards give each sample the same logits alone and inside a padded batch."""
    torch.manual_seed(0)
    agent = make_agent(name, tiny_config(name, n_rotations=4)).eval()
    rng = np.random.default_rng(0)
    x = torch.from_numpy(rng.uniform(0, 1, (3, 6, 64, 32)).astype(np.float32))
    pick_pix = torch.tensor([[10, 5], [40, 20], [60, 30]])
    lang = ["put the red block in the green bowl", "pack the blue block", "stack the blocks"]
    sentence = agent.sentence_features(lang if agent.uses_language else None)
    with torch.no_grad():
        pick = agent._pick_graphs(x, sentence)  # padded to 4
        place = agent._place_graphs(x, pick_pix, sentence)
        for i in range(3):
            one = None if sentence is None else sentence[i : i + 1]
            alone_pick = agent._pick_forward(x[i : i + 1], one)[0]
            alone_place = agent._place_forward(x[i : i + 1], pick_pix[i : i + 1], one)[0]
            torch.testing.assert_close(pick[i], alone_pick, rtol=1e-4, atol=1e-4 * alone_pick.abs().max().item())
            torch.testing.assert_close(place[i], alone_place, rtol=1e-4, atol=1e-4 * alone_place.abs().max().item())
    assert agent._pick_graphs.captured_batch_sizes() == [4] == agent._place_graphs.captured_batch_sizes()
    assert agent._pick_graphs.memory is agent._place_graphs.memory


@pytest.mark.parametrize("name", AGENTS)
def test_dropped_agents_are_freed_without_the_cycle_collector(name: str, fake_capture, tiny_config) -> None:
    config = tiny_config(name, n_rotations=4)
    obs = {"color": np.zeros((64, 32, 3), np.uint8), "height": np.zeros((64, 32), np.float32)}

    def use_once() -> weakref.ref:
        agent = make_agent(name, config)
        agent.act(obs, "pick the red block")
        with torch.no_grad():
            sentence = agent.sentence_features(["a", "b"] if agent.uses_language else None)
            agent._pick_graphs(torch.zeros(2, 6, 64, 32), sentence)
        agent.make_optimizer()
        return weakref.ref(agent)

    # The first agent of a process can stay referenced by frames that a lazy import inside torch's
    # optimiser or open_clip keeps (one-off, not per agent): make those imports happen first.
    use_once()
    gc.collect()
    gc.disable()
    try:
        refs = [use_once() for _ in range(2)]
        assert [r() for r in refs] == [None, None]
    finally:
        gc.enable()


def test_a_copied_agent_gets_its_own_graphs(fake_capture, tiny_config) -> None:
    torch.manual_seed(0)
    agent = make_agent("transporter_only", tiny_config("transporter_only", n_rotations=4))
    x = torch.rand(2, 6, 64, 32)
    with torch.no_grad():
        agent._pick_graphs(x, None)
        twin = copy.deepcopy(agent)
        next(twin.pick.parameters()).data.mul_(2)
        torch.testing.assert_close(twin._pick_graphs(x, None), twin._pick_forward(x, None))
        assert not torch.allclose(twin._pick_graphs(x, None), agent._pick_graphs(x, None))
    assert twin._pick_graphs.memory is twin._place_graphs.memory is not agent._pick_graphs.memory


@pytest.mark.parametrize("name", AGENTS)
def test_warmed_up_forwards_build_no_tensor_from_host_data(name: str, monkeypatch, tiny_config) -> None:
    """CUDA graph capture fails on a host-to-device copy (seen on the first GPU run: the pick head's
    rotation built its matrices from Python numbers): after one eager call, the pick and place forwards
    build no tensor from host data."""
    torch.manual_seed(0)
    agent = make_agent(name, tiny_config(name, n_rotations=4)).eval()
    x = torch.rand(2, 6, 64, 32)
    pick_pix = torch.tensor([[10, 5], [40, 20]])
    sentence = agent.sentence_features(["pack the blue block"] * 2 if agent.uses_language else None)

    def forwards() -> None:
        with torch.no_grad():
            agent._pick_forward(x, sentence)
            agent._place_forward(x, pick_pix, sentence)

    forwards()

    def refuse(*args, **kwargs):
        raise AssertionError("a tensor was built from host data inside a warmed-up forward")

    monkeypatch.setattr(torch, "tensor", refuse)
    monkeypatch.setattr(torch, "as_tensor", refuse)
    forwards()


def test_each_thread_keeps_one_side_stream_per_device(monkeypatch) -> None:
    # cuBLAS keeps a 32 MiB workspace per stream it ran on for the process's life: a stream per agent left that
    # much behind every dropped agent on an H200. Stand-in streams: this machine may have no CUDA.
    made: list[int] = []

    class Stream:
        def __init__(self, index: int) -> None:
            made.append(index)

    monkeypatch.setattr(torch.cuda, "Stream", Stream)
    monkeypatch.setattr(torch.cuda, "device", lambda index: contextlib.nullcontext())
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 1)
    monkeypatch.setattr(cuda_graphs, "_threads", threading.local())
    here = [cuda_graphs.side_stream(torch.device(d)) for d in ("cuda:0", "cuda:0", "cuda", "cuda:1")]
    assert here[0] is here[1] and here[2] is here[3] and here[0] is not here[2]
    there: list[object] = []
    worker = threading.Thread(target=lambda: there.append(cuda_graphs.side_stream(torch.device("cuda:0"))))
    worker.start()
    worker.join()
    assert there[0] is not here[0]
    assert made == [0, 1, 0]
    assert cuda_graphs.side_stream(torch.device("cpu")) is None
