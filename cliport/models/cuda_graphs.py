"""Replay fixed-shape inference forwards as CUDA graphs, so that acting is not bound by kernel launches.

Memory is bounded whatever the number of callers' batch sizes: a call with B samples is padded to the
smallest of :data:`BATCH_SIZES` that holds it (larger batches run in chunks of the largest), so a forward
has at most ``len(BATCH_SIZES)`` graphs per image size, and every graph of one :class:`GraphMemory`
(an agent's pick and place forwards) allocates from one shared memory pool. Graphs of one pool never run
concurrently (one lock), and each keeps its static inputs and output alive, so sharing is safe: a later
capture reuses only the pool memory that earlier graphs freed (their intermediates).
"""

from __future__ import annotations

import contextlib
import copy
import logging
import threading
import weakref
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

log = logging.getLogger(__name__)

WARMUP_ITERS = 3
#: The batch sizes graphs are captured at: a batch is padded up to the next one.
BATCH_SIZES = (1, 2, 4, 8)


class GraphMemory:
    """What the graphs of one owner share: the memory pool, the lock, and whether capture failed.

    One caller at a time: the lock is held from copying the inputs in to cloning the output, and a call
    from another thread's CUDA stream waits (on the device, through an event) for the previous call's
    kernels before it overwrites the static inputs.
    """

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.pool: Any = None  # a graph pool handle, made at the first capture
        self.device: torch.device | None = None
        self.done: Any = None  # a torch.cuda.Event recorded after every graphed call
        self.failed: str | None = None  # why a capture failed: then every call runs eagerly

    def reset(self) -> None:
        """Forget the pool and the failure (after every graph using them is dropped)."""
        with self.lock:
            self.pool, self.device, self.done, self.failed = None, None, None, None

    def __deepcopy__(self, memo: dict[int, Any]) -> GraphMemory:
        return GraphMemory()  # a copy of the owner starts with no graphs


@dataclass
class _Captured:
    graph: Any  # torch.cuda.CUDAGraph (or a test double with replay())
    inputs: tuple[torch.Tensor | None, ...]
    output: torch.Tensor


def _tensor_fingerprint(module: nn.Module) -> tuple[int, ...]:
    """Addresses of every parameter and buffer: they change when any is re-allocated or replaced."""
    return (*(p.data_ptr() for p in module.parameters()), *(b.data_ptr() for b in module.buffers()))


# Walking an agent's module tree takes ~1.5 ms (two_stream: ~1200 tensors), reading the addresses of a
# list of its tensors ~0.05 ms. The tree is walked again only after a parameter, buffer or sub-module was
# registered anywhere (a replaced weight, load_state_dict(assign=True), a new module); in between, the
# cached tensors' addresses are compared (a re-allocation in place: .to(), .data =).
_registrations = 0


def _count_registration(*_: object) -> None:
    global _registrations
    _registrations += 1


def registration_count() -> int:
    """How many parameters, buffers and sub-modules were registered on any module so far: a cached list of a
    module's tensors is stale when this changed since it was walked."""
    return _registrations


for _register in (
    nn.modules.module.register_module_parameter_registration_hook,
    nn.modules.module.register_module_buffer_registration_hook,
    nn.modules.module.register_module_module_registration_hook,
):
    _register(_count_registration)


_threads = threading.local()


def side_stream(device: torch.device) -> Any:
    """The calling thread's side stream on ``device`` (None off CUDA), made at its first use: every warm-up and
    capture of the thread runs there. Each stream cuBLAS runs on holds a workspace of its own (32 MiB on Hopper)
    until the process ends, so a stream per owner or per capture would grow the memory with every agent made."""
    if device.type != "cuda":
        return None
    index = device.index if device.index is not None else torch.cuda.current_device()
    streams: dict[int, Any] = _threads.__dict__.setdefault("streams", {})
    if index not in streams:
        with torch.cuda.device(index):
            streams[index] = torch.cuda.Stream(index)
    return streams[index]


@contextlib.contextmanager
def on_side_stream(device: torch.device) -> Iterator[None]:
    """Run the body on this thread's :func:`side_stream` of ``device`` (a warm-up before a capture), which waits
    for, and is waited for by, the current stream; off CUDA the body just runs."""
    if device.type != "cuda":
        yield
        return
    side = side_stream(device)
    current = torch.cuda.current_stream(device)
    side.wait_stream(current)
    with torch.cuda.stream(side):
        yield
    current.wait_stream(side)


def _capture_cuda(
    fn: Callable[..., torch.Tensor], inputs: tuple[torch.Tensor | None, ...], memory: GraphMemory
) -> tuple[torch.cuda.CUDAGraph, torch.Tensor]:
    """Warm ``fn`` up on a side stream and capture it into the shared pool, all on the inputs' device.

    The stream is the thread's :func:`side_stream` of that device: ``torch.cuda.graph``'s default capture
    stream is created once per process on whatever device was current then. ``thread_local`` capture: other threads
    (a server's, a data loader's) may go on using CUDA while this one captures.
    """
    device = next(t.device for t in inputs if t is not None)
    with torch.cuda.device(device):
        if memory.pool is None:
            memory.pool = torch.cuda.graph_pool_handle()
        with on_side_stream(device):
            for _ in range(WARMUP_ITERS):
                fn(*inputs)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, pool=memory.pool, stream=side_stream(device), capture_error_mode="thread_local"):
            output = fn(*inputs)
    return graph, output


#: How a graph is captured: ``(fn, static inputs, memory) -> (graph with replay(), static output)``.
#: Tests on machines without CUDA replace it with an eager double that has the same buffer semantics.
capture: Callable[..., tuple[Any, torch.Tensor]] = _capture_cuda


class GraphedForward:
    """Calls ``forward(*inputs)`` through CUDA graphs, one per padded batch size and input signature.

    ``forward`` is a method of an ``nn.Module`` (held weakly, so an agent holding its own graphed
    forwards is freed by reference counting, without the cycle collector) or a plain function. It must
    be a pure function of its tensor inputs (and of parameters updated in place), free of host
    synchronisation and shape-dependent control flow, per-sample independent along dimension 0 of every
    input, and return one tensor with the batch first. Inputs are tensors with the batch first, or None.

    The result is a fresh tensor (the graph's output is cloned under the lock), so calls from several
    threads are safe. Graphs are dropped and recaptured when the owner's parameters or buffers are
    re-allocated or replaced (checked at every call, see ``_registrations``); :meth:`clear` drops them by
    hand. Calls under ``torch.inference_mode`` are captured outside it, so later calls work either way.
    If a capture fails, one warning is logged and every later call sharing this memory runs eagerly
    (unpadded) until :meth:`GraphMemory.reset` (an agent resets it at every ``.to()`` and
    ``optimize_for_device``).
    """

    def __init__(
        self,
        forward: Callable[..., torch.Tensor],
        memory: GraphMemory | None = None,
        batch_sizes: Sequence[int] = BATCH_SIZES,
    ) -> None:
        owner = getattr(forward, "__self__", None)
        self._owner = weakref.ref(owner) if isinstance(owner, nn.Module) else None
        self._forward: Callable[[], Callable[..., torch.Tensor] | None]
        if self._owner is not None:
            self._forward = weakref.WeakMethod(forward)
        else:
            self._forward = lambda: forward
        self.memory = memory or GraphMemory()
        self.batch_sizes = tuple(sorted(batch_sizes))
        if not self.batch_sizes or self.batch_sizes[0] < 1:
            raise ValueError(f"batch_sizes must be positive, got {batch_sizes}")
        self._graphs: dict[tuple, _Captured] = {}
        self._tensors: list[torch.Tensor] = []  # the owner's parameters and buffers when last walked
        self._walked_at = -1  # the registration count then
        self._addresses: tuple[int, ...] | None = None  # their addresses when the graphs were captured

    def __len__(self) -> int:
        return len(self._graphs)

    def __deepcopy__(self, memo: dict[int, Any]) -> GraphedForward:
        # A copy of the owner gets a forward bound to the copy, with no graphs (they hold the old addresses).
        fn = self._forward()
        owner = self._owner() if self._owner is not None else None
        if owner is not None and fn is not None:
            fn = fn.__func__.__get__(memo.get(id(owner), owner))  # type: ignore[attr-defined]  # a bound method
        memory = copy.deepcopy(self.memory, memo)
        return GraphedForward(fn, memory, self.batch_sizes)  # type: ignore[arg-type]  # a dead one (None) stays dead

    def captured_batch_sizes(self) -> list[int]:
        """The padded batch sizes of the graphs held now, sorted."""
        return sorted(key[0] for key in self._graphs)

    def clear(self) -> None:
        """Drop every captured graph (its static buffers go back to the pool; the pool is freed when the
        memory's last graph goes)."""
        with self.memory.lock:
            self._drop()

    def _drop(self) -> None:
        if self._graphs and self.memory.device is not None and self.memory.device.type == "cuda":
            torch.cuda.synchronize(self.memory.device)  # no replay may still be reading what is freed
        self._graphs.clear()
        self._addresses = None

    def padded_size(self, b: int) -> int:
        """The batch size a call with ``b`` samples runs at (per chunk of at most the largest size)."""
        return next((s for s in self.batch_sizes if s >= b), self.batch_sizes[-1])

    def _function(self) -> Callable[..., torch.Tensor]:
        fn = self._forward()
        if fn is None:
            raise RuntimeError("the module of this graphed forward no longer exists")
        return fn

    def __call__(self, *inputs: torch.Tensor | None) -> torch.Tensor:
        """``forward(*inputs)``; inputs (B, ...) or None -> output (B, ...)."""
        b = next(t.shape[0] for t in inputs if t is not None)
        if self.memory.failed is not None:
            return self._function()(*inputs)
        largest = self.batch_sizes[-1]
        with torch.inference_mode(False), torch.no_grad(), self.memory.lock:
            self._check_owner()
            if b <= largest:
                return self._run(inputs, b)
            chunks = [
                self._run(tuple(None if t is None else t[i : i + largest] for t in inputs), min(largest, b - i))
                for i in range(0, b, largest)
            ]
            return torch.cat(chunks)

    def _check_owner(self) -> None:
        owner = self._owner() if self._owner is not None else None
        if owner is None:
            return
        if self._walked_at != _registrations:
            self._tensors = [*owner.parameters(), *owner.buffers()]
            self._walked_at = _registrations
        addresses = tuple(map(torch.Tensor.data_ptr, self._tensors))
        if self._addresses is not None and addresses != self._addresses:
            self._drop()
        self._addresses = addresses

    def _run(self, inputs: tuple[torch.Tensor | None, ...], b: int) -> torch.Tensor:
        if self.memory.failed is not None:
            return self._function()(*inputs)
        size = self.padded_size(b)
        key = (size, *(None if t is None else _signature(t) for t in inputs))
        device = next(t.device for t in inputs if t is not None)
        if self.memory.device is not None and self.memory.device != device:
            self._drop()  # moved without clear(): start afresh on the new device
            self.memory.reset()
        captured = self._graphs.get(key)
        cuda = device.type == "cuda"
        if cuda:
            stream = torch.cuda.current_stream(device)
            if self.memory.done is not None:
                stream.wait_event(self.memory.done)
        if captured is None:
            static = tuple(None if t is None else _padded_buffer(t, size) for t in inputs)
            try:
                graph, output = capture(self._function(), static, self.memory)
            except Exception as e:  # noqa: BLE001 - any capture failure means: act eagerly
                self.memory.failed = f"{type(e).__name__}: {e}"
                log.warning(
                    "capturing a CUDA graph of %s failed (%s); acting eagerly from now on",
                    getattr(self._forward(), "__qualname__", "a forward"), self.memory.failed,
                )  # fmt: skip
                self._graphs.clear()
                return self._function()(*inputs)
            captured = self._graphs[key] = _Captured(graph, static, output)
            self.memory.device = device
        for buffer, value in zip(captured.inputs, inputs, strict=True):
            if buffer is not None and value is not None:
                buffer[:b].copy_(value)
                if b < size:
                    buffer[b:].copy_(value[-1:].expand_as(buffer[b:]))
        captured.graph.replay()
        out = captured.output[:b].clone()
        if cuda:
            if self.memory.done is None:
                self.memory.done = torch.cuda.Event()
            self.memory.done.record(stream)
        return out


def _signature(t: torch.Tensor) -> tuple:
    """What a graph's static input is fixed to, besides the batch size: per-sample shape, dtype, device, layout."""
    return (tuple(t.shape[1:]), t.dtype, t.device, _channels_last(t))


def _channels_last(t: torch.Tensor) -> bool:
    return t.dim() == 4 and not t.is_contiguous() and t.is_contiguous(memory_format=torch.channels_last)


def _padded_buffer(t: torch.Tensor, size: int) -> torch.Tensor:
    """A static input buffer for ``t`` (B, ...) with ``size`` rows, in ``t``'s dtype, device and layout,
    filled with ``t`` and copies of its last row (so the padding is a valid input)."""
    buffer = t.new_empty((size, *t.shape[1:]))
    if _channels_last(t):
        buffer = buffer.contiguous(memory_format=torch.channels_last)
    b = t.shape[0]
    buffer[:b].copy_(t)
    if b < size:
        buffer[b:].copy_(t[-1:].expand_as(buffer[b:]))
    return buffer
