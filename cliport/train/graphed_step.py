"""The trainer's optimiser step, run eagerly or replayed whole as one CUDA graph.

At a fixed batch shape on CUDA, :class:`TrainStep` captures forward, loss, backward, the fused Adam step and
the loss bookkeeping (the observers: loss sums, the dead-map watch) into one ``torch.cuda.graph``, so a step
costs one graph launch instead of thousands of kernel launches. How, as PyTorch documents whole-network
capture:

- every tensor the step reads is a static buffer: the batch (colours, heights, target pixels and rotation
  bins as int64 index tensors, copied in from the loader's pinned memory with ``non_blocking``) and the sentence
  features (computed outside, from the encoder's per-string cache, and copied in);
- the first :data:`WARMUP_STEPS` steps are real training steps run eagerly on a side stream (they allocate
  Adam's state, choose the cuDNN and cuFFT plans and, with ``compile``, compile); the next step captures with
  the gradients set to None, so the backward allocates them in the graph's private pool and every replay
  writes them afresh; Adam is fused, its ``capturable`` flag set for the capture;
- the losses stay on the device: the observers add them to device tensors inside the graph, and the trainer
  reads those every ``log_every`` steps.

A step whose inputs differ in shape or dtype from the captured ones, or that comes when the agent's parameters or
buffers were re-allocated (``.to()``, ``load_state_dict(assign=True)``), runs eagerly (after re-allocation the
step warms up and captures again). A capture that fails logs one warning and every later step runs eagerly.
Anything but CUDA, and DDP (the trainer passes ``graphs=False`` there), runs eagerly.

Every step the captured graph replays computes what the eager step computes, with the same kernels: the batch
norms of the frozen CLIP trunk in training mode with each net's own statistics (the ``cliport`` recipe) are
captured as they run (their buffers are swapped in by Python at capture, and updated in place by every replay).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Any

import torch

from cliport.agents.base import PickPlaceAgent
from cliport.agents.loss import LossFn, join_terms, optimizer_step
from cliport.models.cuda_graphs import on_side_stream, registration_count, side_stream
from cliport.models.preprocess import raw_input

log = logging.getLogger(__name__)

#: Eager steps on a side stream before the capture (PyTorch's examples use 3; DDP would need 11).
WARMUP_STEPS = 3
#: Device types a step is captured on. Tests on a machine without CUDA add "cpu" and replace :data:`capture`.
CAPTURE_DEVICES = {"cuda"}
#: The keys of a training step's inputs (:meth:`PickPlaceAgent.training_inputs`), in their order.
INPUTS = ("color", "height", "pick_pix", "place_pix", "place_rot", "sentence")


def _capture_cuda(body: Callable[[], None], device: torch.device, stream: Any) -> Any:
    """Capture ``body`` into a new CUDA graph on ``device``, on ``stream`` (``thread_local``: the loader's
    pin-memory thread may go on allocating pinned memory meanwhile)."""
    with torch.cuda.device(device):
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, stream=stream, capture_error_mode="thread_local"):
            body()
    return graph


#: How a step is captured: ``(body, device, stream) -> graph with replay()``. Tests without CUDA replace it with
#: an eager double that runs ``body`` again at every replay.
capture: Callable[[Callable[[], None], torch.device, Any], Any] = _capture_cuda


class TrainStep:
    """One optimiser step of ``agent`` per call on a training batch (:meth:`__call__`), captured as a CUDA graph
    where it can be (see the module's docstring).

    Args:
        agent: the agent (on its training device, with its speed settings applied).
        optimizer: Adam over its trainable parameters (fused to be captured).
        loss: the recipe's loss (``sample_ce`` or ``cell_mean``).
        autocast_dtype: the autocast dtype of the forward (bfloat16), or None for none.
        observers: functions of each step's (3,) loss terms (:func:`~cliport.agents.loss.pick_place_terms`) that
            only run device work; captured with the step.
        graphs: capture at a fixed batch shape where the device allows (CUDA); False: always eager.
        compile: run the loss through ``torch.compile`` (forward and loss; AOTAutograd compiles the backward),
            inside the captured graph where there is one.
        model: a module whose ``forward(batch) -> (loss, terms)`` replaces the agent's loss on the eager path
            (a DDP-wrapped agent; then ``graphs`` and ``compile`` must be False).
        parallel_heads: on the CPU, differentiate the pick half and the place half of the loss at once, each in
            a thread of its own with half the process's intra-op threads (:meth:`_heads_at_once`); elsewhere, with
            ``compile``, autocast or ``model``, one backward as always. The two halves share no parameter, so
            the gradients are those of the joint loss, rounded as kernels on fewer threads round them.
    """

    def __init__(
        self,
        agent: PickPlaceAgent,
        optimizer: torch.optim.Optimizer,
        loss: str = "sample_ce",
        autocast_dtype: torch.dtype | None = None,
        observers: tuple[Callable[[torch.Tensor], None], ...] = (),
        graphs: bool = True,
        compile: bool = False,
        model: LossFn | None = None,
        parallel_heads: bool = False,
    ) -> None:
        if model is not None and (graphs or compile):
            raise ValueError("a wrapped model (DDP) trains eagerly: pass graphs=False and compile=False")
        self.agent = agent
        self.optimizer = optimizer
        self.loss = loss
        self.autocast_dtype = autocast_dtype
        self.observers = observers
        self.model = model
        self.device = agent.device
        self.graphs = graphs and self.device.type in CAPTURE_DEVICES
        self.loss_fn: Callable[..., tuple[torch.Tensor, torch.Tensor]] = agent._loss_terms
        if compile:
            # No channels_last re-layout of the convolutions on the CPU: PyTorch 2.14's channels_last convolution
            # backward corrupts the heap there (seen compiling transporter_only at width 0.125).
            options: dict[str, str | int | bool | Callable[..., Any]] | None = None
            if self.device.type == "cpu":
                options = {"layout_optimization": False}
            self.loss_fn = torch.compile(agent._loss_terms, dynamic=False, options=options)
        #: Whether eager steps differentiate the pick and place halves at once (see ``parallel_heads``).
        self.parallel_heads = (
            parallel_heads and self.device.type == "cpu" and not compile and autocast_dtype is None and model is None
        )
        self._head_threads = max(1, torch.get_num_threads() // 2)
        self._place_thread = ThreadPoolExecutor(1, thread_name_prefix="place-head") if self.parallel_heads else None
        #: Why capturing failed (then every step is eager), or None.
        self.failed: str | None = None
        #: Steps run so far by replaying the graph, and eagerly (warm-up steps and fall-backs included).
        self.replays = 0
        self.eager_steps = 0
        self._static: dict[str, torch.Tensor | None] | None = None
        self._signature: tuple | None = None
        self._graph: Any = None
        self._warmed = 0
        self._keep: list[torch.Tensor] = []  # the graph's gradients, alive while it is
        self._tensors: list[torch.Tensor] = []
        self._walked_at = -1
        self._addresses: tuple[int, ...] | None = None

    @property
    def captured(self) -> bool:
        """Whether a captured graph is held now."""
        return self._graph is not None

    def reset(self) -> None:
        """Drop the captured graph (the next steps warm up and capture again), e.g. after replacing the
        optimiser's state tensors by hand."""
        if self._graph is not None and self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        self._graph, self._static, self._signature, self._keep = None, None, None, []
        self._warmed, self._addresses = 0, None

    def _autocast(self) -> contextlib.AbstractContextManager[Any]:
        if self.autocast_dtype is None:
            return contextlib.nullcontext()
        # No cast cache: a capture must not reuse casts made before it (and eager steps compute the same).
        return torch.autocast(self.device.type, dtype=self.autocast_dtype, cache_enabled=False)

    def __call__(self, batch: dict[str, Any]) -> None:
        """One optimiser step on ``batch`` (a training batch as :meth:`PickPlaceAgent.training_inputs` reads it).
        Nothing is read back to the host: the observers hold the losses."""
        if self.model is not None:
            self._observe(optimizer_step(self.model, batch, self.optimizer, self._autocast()))
            self.eager_steps += 1
            return
        inputs = self.agent.training_inputs(batch, device=torch.device("cpu"))
        host: dict[str, torch.Tensor | None] = {key: inputs[key] for key in INPUTS}  # type: ignore[literal-required]  # INPUTS are TrainingInputs' keys
        if self.graphs and self.failed is None:
            signature = tuple(None if t is None else (t.shape, t.dtype) for t in host.values())
            self._check_addresses()
            if self._static is None:
                self._static = {
                    k: None if t is None else torch.empty_like(t, device=self.device) for k, t in host.items()
                }
                self._signature = signature
            if signature == self._signature:
                self._graphed(host)
                return
        self._eager(host)

    def _observe(self, terms: torch.Tensor) -> None:
        for observe in self.observers:
            observe(terms)

    def _body(self, inputs: dict[str, torch.Tensor | None]) -> None:
        with self._autocast():
            total, terms = self.loss_fn(**inputs, loss=self.loss)
        total.backward()
        self.optimizer.step()
        self._observe(terms)

    def _eager(self, host: dict[str, torch.Tensor | None]) -> None:
        inputs = {k: None if t is None else t.to(self.device, non_blocking=True) for k, t in host.items()}
        self.agent.train()
        self.optimizer.zero_grad(set_to_none=True)
        if self.parallel_heads:
            self._heads_at_once(inputs)
        else:
            self._body(inputs)
        self.eager_steps += 1

    def _heads_at_once(self, inputs: dict[str, Any]) -> None:
        """The eager step with the place half's forward and backward in a second thread while this one does the
        pick half's, each on half the intra-op threads: on a 2-core CPU, where one small net's kernels use a
        second core poorly, a step takes ~0.65x the time (docs/language-lesson.md has the measurements)."""
        assert self._place_thread is not None
        x = raw_input(inputs["color"], inputs["height"])
        pick_pix, sentence = inputs["pick_pix"], inputs["sentence"]

        def place() -> torch.Tensor:
            share, place_loss = self.agent._place_loss_terms(
                x, pick_pix, inputs["place_pix"], inputs["place_rot"], sentence, self.loss
            )
            share.backward()
            return place_loss

        threads = torch.get_num_threads()
        torch.set_num_threads(self._head_threads)  # a new thread takes this count when it first computes
        try:
            other = self._place_thread.submit(place)
            try:
                share, pick_loss = self.agent._pick_loss_terms(x, pick_pix, sentence, self.loss)
                share.backward()
            except BaseException:
                wait([other])
                raise
            place_loss = other.result()
        finally:
            torch.set_num_threads(threads)
        self.optimizer.step()
        self._observe(join_terms(pick_loss, place_loss))

    def _graphed(self, host: dict[str, torch.Tensor | None]) -> None:
        static = self._static
        assert static is not None
        for key, value in host.items():
            buffer = static[key]
            if buffer is not None and value is not None:
                buffer.copy_(value, non_blocking=True)
        if self._graph is not None:
            self._graph.replay()
            self.replays += 1
            return
        self.agent.train()
        if self._warmed < WARMUP_STEPS:
            with on_side_stream(self.device):
                self.optimizer.zero_grad(set_to_none=True)
                self._body(static)
            self._warmed += 1
            self.eager_steps += 1
            return
        self.optimizer.zero_grad(set_to_none=True)  # the capture's backward allocates them in the graph's pool
        fused = [group.get("fused") for group in self.optimizer.param_groups]
        if not all(fused):
            self._fail("the optimiser is not fused Adam (fused_adam is off)")
            self._eager(host)
            return
        flags = [group["capturable"] for group in self.optimizer.param_groups]
        try:
            for group in self.optimizer.param_groups:
                group["capturable"] = True  # fused Adam's arithmetic is the same either way
            graph = capture(lambda: self._body(static), self.device, side_stream(self.device))
        except Exception as e:  # noqa: BLE001 - any capture failure means: train eagerly
            self.optimizer.zero_grad(set_to_none=True)
            self._fail(f"{type(e).__name__}: {e}")
            self._eager(host)
            return
        finally:
            for group, flag in zip(self.optimizer.param_groups, flags, strict=True):
                group["capturable"] = flag
        self._graph = graph
        self._keep = [p.grad for p in self.agent.parameters() if p.grad is not None]
        if self.device.type == "cuda":
            torch.cuda.empty_cache()  # the warm-up's cached blocks; the graph keeps its own pool
        self._graph.replay()
        self.replays += 1

    def _fail(self, why: str) -> None:
        self.failed = why
        self.reset()
        log.warning("capturing the training step as a CUDA graph failed (%s); training eagerly from now on", why)

    def _check_addresses(self) -> None:
        """Drop the graph if any parameter or buffer of the agent was re-allocated or replaced since capture."""
        if self._walked_at != registration_count():
            self._tensors = [*self.agent.parameters(), *self.agent.buffers()]
            self._walked_at = registration_count()
        addresses = tuple(map(torch.Tensor.data_ptr, self._tensors))
        if self._addresses is not None and addresses != self._addresses:
            self.reset()
        self._addresses = addresses
