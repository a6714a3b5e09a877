"""Replay a fixed-shape inference forward as a CUDA graph, so that acting is not bound by kernel launches."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

WARMUP_ITERS = 3


@dataclass
class _Captured:
    graph: torch.cuda.CUDAGraph
    inputs: tuple[torch.Tensor | None, ...]
    output: torch.Tensor


class GraphedForward:
    """Calls ``fn(*inputs)`` through a CUDA graph captured once per input signature (shapes, strides, dtypes).

    ``fn`` must be a pure function of its tensor inputs (and of module parameters updated in place),
    free of host synchronisation and shape-dependent control flow, returning one tensor. The first call
    with a new signature warms ``fn`` up on a side stream and captures it (as the torch.cuda.graphs
    documentation requires); later calls copy the inputs into the graph's static buffers and replay.
    The returned tensor is the graph's static output: it is overwritten by the next replay, so callers
    must consume or clone it first. Only for inference (call under ``torch.no_grad()``); ``clear()``
    whenever parameters are re-allocated (``.to()``, dtype or layout changes).
    """

    def __init__(self, fn: Callable[..., torch.Tensor]) -> None:
        self.fn = fn
        self._graphs: dict[tuple, _Captured] = {}

    def __len__(self) -> int:
        return len(self._graphs)

    def clear(self) -> None:
        """Drop every captured graph (and its memory pool)."""
        self._graphs.clear()

    @staticmethod
    def _signature(inputs: tuple[torch.Tensor | None, ...]) -> tuple:
        return tuple(None if t is None else (tuple(t.shape), t.stride(), t.dtype, t.device) for t in inputs)

    def __call__(self, *inputs: torch.Tensor | None) -> torch.Tensor:
        key = self._signature(inputs)
        captured = self._graphs.get(key)
        if captured is None:
            captured = self._graphs[key] = self._capture(inputs)
        else:
            for static, value in zip(captured.inputs, inputs, strict=True):
                if static is not None:
                    static.copy_(value)
        captured.graph.replay()
        return captured.output

    def _capture(self, inputs: tuple[torch.Tensor | None, ...]) -> _Captured:
        static = tuple(None if t is None else t.clone() for t in inputs)
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(WARMUP_ITERS):
                self.fn(*static)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            output = self.fn(*static)
        return _Captured(graph, static, output)
