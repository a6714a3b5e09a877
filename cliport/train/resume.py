"""Resuming optimiser state saved on another device, layout or optimiser implementation.

A run's ``last.pt`` keeps Adam's moments with the strides, dtype and device they had when saved: NCHW
for a run started on a CPU, before the CUDA speed work or with channels_last off, channels_last for one
saved on CUDA. ``torch.optim.Optimizer.load_state_dict`` keeps those strides, and it also takes the
implementation flags (``fused``, ``foreach``) from the file instead of from the optimiser built for
this device. Fused CUDA Adam then rejects moments whose layout differs from their parameter's.
"""

from __future__ import annotations

from typing import Any

import torch

#: Param-group keys that choose an implementation for this device rather than describe the training.
IMPLEMENTATION_KEYS = ("fused", "foreach", "capturable", "differentiable")


def load_optimizer_state(optimizer: torch.optim.Optimizer, state: dict[str, Any]) -> None:
    """Load a saved ``optimizer.state_dict()`` so that it works with this optimiser's parameters as they are.

    Hyper-parameters (learning rate, betas, ...) come from ``state``; the implementation flags
    (:data:`IMPLEMENTATION_KEYS`) stay this optimiser's. Every state tensor shaped like its parameter (Adam's
    ``exp_avg``, ``exp_avg_sq``) is copied into the parameter's dtype, device and strides (channels_last or
    not); ``step`` goes where the implementation wants it (float32 on the parameter's device for fused or
    capturable Adam, on the CPU otherwise). Nothing is shared with ``state``: it can be loaded again.
    """
    own = [{k: group[k] for k in IMPLEMENTATION_KEYS if k in group} for group in optimizer.param_groups]
    optimizer.load_state_dict(state)
    for group, implementation in zip(optimizer.param_groups, own, strict=True):
        group.update(implementation)
        on_device = bool(group.get("fused") or group.get("capturable"))
        for param in group["params"]:
            param_state = optimizer.state.get(param)
            if not param_state:
                continue
            for key, value in param_state.items():
                if not isinstance(value, torch.Tensor):
                    continue
                if key == "step":
                    device = param.device if on_device else torch.device("cpu")
                    param_state[key] = value.to(device=device, dtype=torch.float32, copy=True)
                elif value.shape == param.shape:
                    param_state[key] = torch.empty_like(param).copy_(value)
