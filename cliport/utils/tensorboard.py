"""TensorBoard event files of training, validation and evaluation (``tensorboard --logdir runs/``).

Each writer owns its folder: a run's training events go to ``RUN/tensorboard/``, its validation events to
``RUN/tensorboard/val/`` (written by another process while training goes on; TensorBoard reads only the
newest event file of a folder while it is live) and evaluation events next to the result JSONs.
"""

from __future__ import annotations

from typing import Any

#: Seconds between flushes of pending events to disk (TensorBoard's own default is 120).
FLUSH_SECONDS = 30


def summary_writer(folder: str, purge_step: int | None = None) -> Any:
    """A ``torch.utils.tensorboard.SummaryWriter`` writing into ``folder``. ``purge_step``: on a resumed run,
    the first step logged again; TensorBoard hides events of an earlier file at or after it."""
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(folder, purge_step=purge_step, flush_secs=FLUSH_SECONDS)


def log_gpu_memory(writer: Any, device: Any, step: int) -> None:
    """On a CUDA ``device``: ``gpu/allocated_gib`` (tensors now), ``gpu/peak_allocated_gib`` (the most so far)
    and ``gpu/reserved_gib`` (held by PyTorch's caching allocator); nothing on other devices."""
    if getattr(device, "type", None) != "cuda":
        return
    import torch

    gib = 2**30
    writer.add_scalar("gpu/allocated_gib", torch.cuda.memory_allocated(device) / gib, step)
    writer.add_scalar("gpu/peak_allocated_gib", torch.cuda.max_memory_allocated(device) / gib, step)
    writer.add_scalar("gpu/reserved_gib", torch.cuda.memory_reserved(device) / gib, step)


def log_result(writer: Any, prefix: str, result: dict[str, Any], step: int) -> None:
    """The summary of an evaluation (``cliport.evaluation.evaluate.summarise``) as scalars under ``prefix``,
    all in percent: ``mean_score`` with ``mean_score_ci95_low/high`` (normal 95% interval) and ``success``
    with ``success_ci95_low/high`` (Wilson 95% interval)."""
    low, high = result["ci95"]
    success_low, success_high = result["success_ci95"]
    scalars = {
        "mean_score": result["mean_score"],
        "mean_score_ci95_low": low,
        "mean_score_ci95_high": high,
        "success": 100.0 * result["success_rate"],
        "success_ci95_low": success_low,
        "success_ci95_high": success_high,
    }
    for name, value in scalars.items():
        writer.add_scalar(f"{prefix}/{name}", float(value), step)


__all__ = ["FLUSH_SECONDS", "log_gpu_memory", "log_result", "summary_writer"]
