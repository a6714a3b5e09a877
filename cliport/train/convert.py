"""Checkpoints of the reference CLIPort code (PyTorch Lightning ``.ckpt`` files) as cliport run folders.

The reference saves its agent's ``state_dict`` (``attention.*``: pick; ``transport.*``: place key and
query) inside a Lightning checkpoint. Our nets are the reference's layer for layer, so the conversion is a
renaming (:mod:`cliport.models.reference_names`) plus what the reference keeps beside the weights:

- its three CLIP copies (pick, key, query) each hold batch-norm running statistics that its training let
  drift; the converted agent keeps each net's own (``per_net_clip_stats``) and shares one CLIP's weights,
  which must equal the copies' weights (checked);
- its rotation count is not in the file (the reference's configs use 36; ``n_rotations``), its query crop
  is 64 pixels and its nets are full width.

The file is read with :func:`cliport.utils.safe_pickle.load_torch_checkpoint`: nothing in it runs.
The run folder gets ``config.json``, ``checkpoints/step-<global step>.pt`` and ``last.pt`` (with a fresh
optimiser: the reference keeps its Adam state outside Lightning, so the file holds none) and
``converted.json`` (source file, sha256, reference agent, Lightning bookkeeping).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from cliport.errors import CheckpointError, ConfigError, RunDirError
from cliport.models import reference_names
from cliport.utils.files import save_torch, write_json
from cliport.utils.run_dir import RunDir

if TYPE_CHECKING:  # imported where used: cliport-convert --help reads the names and counts above without torch
    import torch

#: The reference's agent names we can convert, and ours.
SUPPORTED: dict[str, str] = {ref: ours for ours, refs in reference_names.REFERENCE_AGENTS.items() for ref in refs}
#: A key only each reference agent's state dict has (its pick net's first layer, or a lateral fusion).
_SIGNATURES = {
    "transporter": ("attention.attn_stream.layers.0.weight",),
    "cliport": ("attention.attn_stream_two.lat_fusion1.conv.1.weight", "attention.attn_stream_two.lang_proj1.weight"),
    "clip_lingunet_transporter": ("attention.attn_stream_one.lang_proj1.weight",),
}
#: The reference's query crop size (fixed in its code) and rotation count (its configs' value).
REFERENCE_CROP = 64
REFERENCE_N_ROTATIONS = 36
CONVERTED = "converted.json"
_RUN_NAME = re.compile(r"(?P<task>.+)-(?P<agent>[a-z0-9_]+)-n(?P<n>\d+)-train")


def supported_line() -> str:
    names = ", ".join(f"{ref} (-> {ours})" for ref, ours in SUPPORTED.items())
    return f"supported reference agent types: {names}"


@dataclass
class ReferenceCheckpoint:
    """What a reference checkpoint holds that the conversion uses."""

    path: str
    sha256: str
    state_dict: dict[str, torch.Tensor]
    global_step: int | None
    epoch: int | None
    lightning_version: str | None


def _sha256(path: str) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_reference_checkpoint(path: str) -> ReferenceCheckpoint:
    """The reference checkpoint at ``path``; a one-line :class:`CheckpointError` (or the safe loader's
    errors) when it cannot be read or is not a CLIPort checkpoint."""
    import torch

    from cliport.utils.safe_pickle import load_torch_checkpoint

    payload = load_torch_checkpoint(path)
    state = payload.get("state_dict") if isinstance(payload, dict) else None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise CheckpointError(
            f"{path} is not a PyTorch Lightning checkpoint (no state_dict of tensors); {supported_line()}"
        )
    if not any(k.startswith(("attention.", "transport.")) for k in state):
        raise CheckpointError(
            f"{path} is not a CLIPort checkpoint (no attention.* or transport.* weights); {supported_line()}"
        )

    def number(key: str) -> int | None:
        value = payload.get(key)
        return int(value) if isinstance(value, int) else None

    version = payload.get("pytorch-lightning_version")
    return ReferenceCheckpoint(
        path=os.path.abspath(path),
        sha256=_sha256(path),
        state_dict=dict(state),
        global_step=number("global_step"),
        epoch=number("epoch"),
        lightning_version=version if isinstance(version, str) else None,
    )


def detect_agent_type(ckpt: ReferenceCheckpoint) -> str:
    """The reference agent name whose nets the state dict holds; CheckpointError for any other."""
    keys = ckpt.state_dict
    if any(".text_fc." in k for k in keys):
        raise CheckpointError(
            f"{ckpt.path} is a checkpoint of a reference RN50-BERT agent, whose released nets cannot run "
            f"(docs/agents.md); {supported_line()}"
        )
    found = [name for name, signature in _SIGNATURES.items() if all(k in keys for k in signature)]
    if found == ["clip_lingunet_transporter"] and any(k.startswith("attention.attn_stream_two.") for k in keys):
        found = []
    if len(found) != 1:
        raise CheckpointError(
            f"{ckpt.path} holds a reference agent type cliport does not have (e.g. a U-Net, image-goal or "
            f"language-free ablation); give --agent-type if it is one of ours; {supported_line()}"
        )
    return found[0]


def task_from_path(path: str) -> tuple[str, int] | None:
    """(task, n_demos) from the reference's run-folder naming ``{task}-{agent}-n{N}-train`` on the path,
    when the task is one of ours (reference agent names have no dashes, so the split is unique)."""
    from cliport import tasks

    known = set(tasks.names()) | set(tasks.groups())
    for part in reversed(os.path.abspath(path).split(os.sep)):
        match = _RUN_NAME.fullmatch(part)
        if match and match["task"] in known:
            return match["task"], int(match["n"])
    return None


def _clip_copies(agent: str, state: dict[str, torch.Tensor]) -> list[dict[str, torch.Tensor]]:
    """Each net's CLIP copy (keys as in OpenAI's model), pick first."""
    return [
        {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
        for prefix in reference_names.frozen_prefixes(agent)
    ]


def _is_stat(name: str) -> bool:
    return name.endswith(("running_mean", "running_var", "num_batches_tracked"))


def _check_clip(path: str, copies: list[dict[str, torch.Tensor]], encoder: Any, source: str) -> None:
    """The copies' weights are one frozen CLIP, and the one the run loads from ``source``."""
    import torch

    first = copies[0]
    if not first:
        raise CheckpointError(f"{path} holds no CLIP weights (clip_rn50.*) for its nets")
    for other in copies[1:]:
        differing = [k for k, v in first.items() if not _is_stat(k) and not torch.equal(v, other.get(k, v + 1))]
        if differing:
            raise CheckpointError(f"{path}: its nets' CLIP copies differ in {differing[0]}: not a frozen CLIP")
    ours = encoder.model.state_dict()
    for key, value in first.items():
        if _is_stat(key) or key in ("input_resolution", "context_length", "vocab_size"):
            continue
        mine = ours.get(key)
        if mine is None or mine.shape != value.shape or not torch.equal(mine.to(value.dtype), value):
            raise CheckpointError(
                f"the CLIP weights of {source!r} are not the ones {path} was trained with (first difference: "
                f"{key}); pass --clip-weights checkpoint to use the checkpoint's own copy"
            )


def convert_checkpoint(
    path: str,
    run_dir: str,
    agent_type: str | None = None,
    task: str | None = None,
    n_rotations: int = REFERENCE_N_ROTATIONS,
    clip_weights: str = "openai",
) -> dict[str, Any]:
    """Write the run folder ``run_dir`` from the reference checkpoint ``path``; returns a summary.

    ``agent_type``: the reference's agent name, checked against the one detected from the keys. ``task``: the run's task
    (default: from the reference's folder naming on the path). ``clip_weights``: where the converted run
    loads CLIP from, as for training (``openai``, a tag or a file), or ``checkpoint``: the checkpoint's own
    copy, written to ``run_dir/clip-rn50.pt``; either way it must equal the checkpoint's CLIP weights.
    """
    run = RunDir(run_dir)
    if run.is_run() or run.has_progress():
        raise RunDirError(f"{run_dir} already holds a run; choose another --run-dir")
    ckpt = read_reference_checkpoint(path)
    if agent_type is not None and agent_type not in SUPPORTED:
        raise ConfigError(f"unknown --agent-type {agent_type!r}; {supported_line()}")
    detected = detect_agent_type(ckpt)
    if agent_type is not None and agent_type != detected:
        raise CheckpointError(f"{ckpt.path} does not hold the {agent_type} agent's nets: they are {detected}'s")
    n_demos = 1000
    if task is None:
        found = task_from_path(path)
        if found is None:
            raise ConfigError(
                f"cannot tell the task of {path} from its path (the reference's folders are named "
                "{task}-{agent}-n{N}-train): pass --task"
            )
        task, n_demos = found
    if clip_weights == "random":
        raise ConfigError("--clip-weights random makes no sense for a trained checkpoint: give its CLIP")

    created = not os.path.exists(run_dir)
    try:
        return _write_run(ckpt, detected, run, task, n_demos, n_rotations, clip_weights)
    except BaseException:
        if created:
            shutil.rmtree(run_dir, ignore_errors=True)
        raise


def _write_run(
    ckpt: ReferenceCheckpoint, detected: str, run: RunDir, task: str, n_demos: int, n_rotations: int, clip_weights: str
) -> dict[str, Any]:
    import torch

    from cliport.agents import make_agent
    from cliport.train.config import TrainConfig

    ours, run_dir = SUPPORTED[detected], run.root
    agent_config: dict[str, Any] = {"width": 1.0, "crop_size": REFERENCE_CROP, "n_rotations": n_rotations}
    copies = _clip_copies(ours, ckpt.state_dict) if ours != "transporter_only" else []
    if copies:
        if clip_weights == "checkpoint":
            os.makedirs(run_dir, exist_ok=True)
            clip_weights = os.path.abspath(os.path.join(run_dir, "clip-rn50.pt"))
            save_torch(copies[0], clip_weights)
        agent_config.update(clip_weights=clip_weights, per_net_clip_stats=True)
    config = TrainConfig.build(
        {"agent": ours, "task": task, "n_demos": n_demos, "run_dir": run_dir, "env": {"camera_scale": 1.0},
         "agent_config": agent_config, "recipe": "cliport"}
    )  # fmt: skip
    agent = make_agent(ours, config.agent_config)
    if copies:
        _check_clip(ckpt.path, copies, agent.encoder, clip_weights)
    try:
        state = reference_names.from_reference(ours, ckpt.state_dict, agent.trainable_state_dict())
    except ValueError as err:
        raise CheckpointError(f"{ckpt.path} does not hold the {detected} agent's nets: {err}") from None
    agent.load_trainable_state_dict(state)

    provenance = {
        "file": ckpt.path,
        "sha256": ckpt.sha256,
        "reference_agent": detected,
        "agent": ours,
        "global_step": ckpt.global_step,
        "epoch": ckpt.epoch,
        "pytorch_lightning_version": ckpt.lightning_version,
        "n_rotations": n_rotations,
        "clip_weights": agent_config.get("clip_weights"),
        "clip_precision": "fp32 (bf16 trunk on CUDA unless switched off); the reference ran CLIP in fp16",
    }
    step = ckpt.global_step or 0
    torch.manual_seed(config.seed)
    trainer = {"step": step, "optimizer": agent.make_optimizer().state_dict(), "torch_rng": torch.get_rng_state()}
    os.makedirs(run_dir, exist_ok=True)
    write_json(run.config, config.to_dict())
    # One file is both the scheduled checkpoint and the resume point (last.pt is a hard link to it: training
    # replaces last.pt atomically, which leaves the converted checkpoint as it is).
    payload = {**agent.checkpoint_payload(), "recipe": "cliport", "converted_from": provenance, "trainer": trainer}
    save_torch(payload, run.checkpoint(step))
    try:
        os.link(run.checkpoint(step), run.checkpoint("last"))
    except OSError:
        shutil.copyfile(run.checkpoint(step), run.checkpoint("last"))
    write_json(os.path.join(run_dir, CONVERTED), provenance)
    return {"run_dir": run_dir, "checkpoint": run.checkpoint(step), "task": task, **provenance}
