"""An agent's weights on disk: the checkpoint format, safetensors weights files, ``save_pretrained`` folders,
and which file ``from_pretrained`` reads for a run folder, a pretrained folder or ``hf://`` name.

A checkpoint payload (see ``PickPlaceAgent.checkpoint_payload``) is a dict of ``format``, ``cliport_version``,
``agent``, ``config``, ``clip_weights``, ``weight_sources`` and the trainable ``state_dict``; a ``.pt``
checkpoint is that dict saved with torch, a ``.safetensors`` weights file its tensors with the rest as string
metadata. A checkpoint holds the trainable tensors only (:func:`trainable_state`): frozen pretrained encoders are
reloaded from the sources it records. Nothing here imports an agent: ``PickPlaceAgent.from_pretrained`` builds
one from a payload.
"""

from __future__ import annotations

import json
import os
from typing import TYPE_CHECKING, Any

from cliport import __version__
from cliport.errors import CheckpointError, ConfigError, RunDirError
from cliport.utils.files import save_safetensors, write_json
from cliport.utils.hub import resolve_run_dir

if TYPE_CHECKING:
    import torch
    from torch import nn

#: 2 since the networks compute the reference CLIPort's functions (cliport 0.2.0); 1 before.
CHECKPOINT_FORMAT = 2
#: What ``save_pretrained`` writes into a folder: the trainable weights and a description of the agent.
PRETRAINED_WEIGHTS = "model.safetensors"
PRETRAINED_CONFIG = "config.json"
#: The payload entries that describe the agent (``config.json`` of a pretrained folder holds them).
DESCRIPTION_KEYS = ("agent", "config", "clip_weights", "weight_sources")


def weights_metadata(payload: dict[str, Any], step: int | None = None) -> dict[str, str]:
    """The string metadata of a safetensors weights file: a checkpoint payload's agent, config and weight
    sources (JSON), its format and version, and the training step when known."""
    metadata = {
        "format": str(payload["format"]),
        "cliport_version": str(payload.get("cliport_version", "")),
        "agent": payload["agent"],
        "config": json.dumps(payload["config"]),
        "clip_weights": json.dumps(payload.get("clip_weights")),
        "weight_sources": json.dumps(payload.get("weight_sources", {})),
    }
    if step is not None:
        metadata["step"] = str(int(step))
    return metadata


def save_weights(payload: dict[str, Any], path: str | os.PathLike[str], step: int | None = None) -> None:
    """Write a checkpoint payload's trainable weights as a safetensors file (no pickle), its agent, config and
    weight sources in the file's metadata, atomically. :func:`read_weights` reads it back."""
    save_safetensors(payload["state_dict"], path, weights_metadata(payload, step))


def save_pretrained_folder(payload: dict[str, Any], folder: str | os.PathLike[str]) -> str:
    """Write a checkpoint payload as ``folder/model.safetensors`` and ``folder/config.json`` (see
    ``PickPlaceAgent.save_pretrained``); RunDirError for a training run's folder. Returns the folder."""
    config_path = os.path.join(folder, PRETRAINED_CONFIG)
    if os.path.isfile(config_path):
        with open(config_path) as f:
            existing = json.load(f)
        if isinstance(existing, dict) and "task" in existing:
            raise RunDirError(f"{folder} holds a training run: save_pretrained into another folder")
    save_weights(payload, os.path.join(folder, PRETRAINED_WEIGHTS))
    description = {k: payload[k] for k in DESCRIPTION_KEYS}
    write_json(config_path, {**description, "format": CHECKPOINT_FORMAT, "cliport_version": __version__})
    return str(folder)


def frozen_prefixes(module: nn.Module) -> tuple[str, ...]:
    """The state-dict prefixes (``"pick.net.encoder."``, ...) of every frozen pretrained encoder in ``module``,
    under each name it sits under (one encoder is shared by several nets)."""
    from cliport.models.encoders.base import FrozenEncoder

    modules = module.named_modules(remove_duplicate=False)
    return tuple(name + "." for name, child in modules if isinstance(child, FrozenEncoder))


def trainable_state(module: nn.Module) -> dict[str, torch.Tensor]:
    """``module``'s state dict without any frozen encoder tensor."""
    prefixes = frozen_prefixes(module)
    return {k: v for k, v in module.state_dict().items() if not (prefixes and k.startswith(prefixes))}


def load_trainable_state(module: nn.Module, state: dict[str, torch.Tensor]) -> None:
    """Load weights saved by :func:`trainable_state` into ``module``; KeyError naming the tensors missing (every
    trainable one must be present) or unexpected."""
    missing, unexpected = module.load_state_dict(state, strict=False)
    prefixes = frozen_prefixes(module)
    missing = [k for k in missing if not (prefixes and k.startswith(prefixes))]
    if missing or unexpected:
        raise KeyError(f"checkpoint mismatch: missing {missing}, unexpected {unexpected}")


def check_format(path: str | os.PathLike[str], written: int) -> None:
    """CheckpointError naming ``path`` unless ``written`` is this cliport's :data:`CHECKPOINT_FORMAT`."""
    if written < CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"{path} was written by cliport before 0.2.0 (checkpoint format {written}), whose networks differ from "
            "the reference CLIPort's (docs/parity.md) and cannot load these weights; retrain it"
        )
    if written > CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path} was written by a newer cliport (checkpoint format {written}); upgrade cliport")


def read_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A checkpoint's payload (see ``PickPlaceAgent.checkpoint_payload``); CheckpointError if unusable, or
    written with another checkpoint format (format 1: the networks from before reference parity)."""
    from cliport.utils.files import load_torch

    payload = load_torch(path)
    if not isinstance(payload, dict) or not {"agent", "config", "state_dict"} <= set(payload):
        raise CheckpointError(f"{path} is not a cliport checkpoint (no agent, config and weights)")
    check_format(path, payload.get("format", 1))
    return payload


def read_weights(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A safetensors weights file (``save_weights``, ``save_pretrained``, a run's ``model.safetensors``) as a
    checkpoint payload (``agent``, ``config``, ``clip_weights``, ``weight_sources``, ``state_dict``, and ``step``
    where recorded), read without pickle; CheckpointError if unusable or not written by cliport."""
    from cliport.utils.files import load_safetensors

    tensors, metadata = load_safetensors(path)
    if not {"format", "agent", "config"} <= set(metadata):
        raise CheckpointError(f"{path} is not a cliport weights file (no agent and config in its metadata)")
    try:
        written = int(metadata["format"])
        payload: dict[str, Any] = {
            "format": written,
            "cliport_version": metadata.get("cliport_version"),
            "agent": metadata["agent"],
            "config": json.loads(metadata["config"]),
            "clip_weights": json.loads(metadata.get("clip_weights", "null")),
            "weight_sources": json.loads(metadata.get("weight_sources", "{}")),
            "state_dict": tensors,
        }
        if "step" in metadata:
            payload["step"] = int(metadata["step"])
    except ValueError as e:  # json.JSONDecodeError is a ValueError
        raise CheckpointError(f"{path} has malformed cliport metadata: {e}") from e
    check_format(path, written)
    return payload


def read_payload(path: str) -> dict[str, Any]:
    """The payload of a weights file: :func:`read_weights` for ``.safetensors``, else :func:`read_checkpoint`."""
    return read_weights(path) if path.endswith(".safetensors") else read_checkpoint(path)


def pretrained_file(source: str, checkpoint: str | int | None = None) -> str:
    """The weights file ``PickPlaceAgent.from_pretrained`` reads for ``source`` and ``checkpoint``;
    RunDirError / ConfigError naming the problem."""
    from cliport.utils.run_dir import RunDir

    source = resolve_run_dir(source)  # hf://org/name[@revision] from the Hugging Face cache; a local path as given
    if os.path.isfile(source):
        if checkpoint is not None:
            raise ConfigError(f"checkpoint={checkpoint!r} needs a run folder, not the file {source}")
        return source
    if not os.path.isdir(source):
        raise RunDirError(f"no run folder or weights file at {source}")
    run = RunDir(source)
    if checkpoint is None:
        if os.path.isfile(run.model_weights):
            return run.model_weights
        steps = run.checkpoint_steps()  # a run from before safetensors weights: its newest scheduled checkpoint
        if not steps:
            raise RunDirError(f"{source} holds no {PRETRAINED_WEIGHTS} and no scheduled checkpoints")
        return run.checkpoint(steps[-1])
    (step,) = run.resolve(str(checkpoint), run.best_step() if checkpoint == "best" else None, allow_all=False)
    if isinstance(step, str):  # LAST
        return run.checkpoint(step)
    return run.weights(step) if os.path.isfile(run.weights(step)) else run.checkpoint(step)
