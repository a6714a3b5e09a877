"""What ``cliport-pretrain`` leaves: the pretrained encoder in open_clip's own format, and its resumable state.

The weights are the open_clip model's state dict, as a safetensors file named as open_clip names a local or hub
model's weights (:data:`WEIGHTS_FILE`), beside open_clip's config file of the model (:data:`CONFIG_FILE`:
``model_cfg`` and ``preprocess_cfg``). So the folder is what ``open_clip.create_model("local-dir:FOLDER")`` reads,
and the file is what ``--clip-weights FILE --semantic-encoder NAME`` loads through the path every CLIP weights
file takes (:func:`cliport.models.encoders.clip_weights.build_clip_model`: architecture checked, loaded
strictly). Its metadata names the model (so a wrong ``--semantic-encoder`` is said in one line), the source and the
steps trained.
"""

from __future__ import annotations

import json
import os
from typing import Any

import torch

from cliport import __version__
from cliport.models.encoders.clip_registry import model_config
from cliport.models.encoders.clip_weights import MODEL_NAME_KEY
from cliport.utils.files import load_safetensors, save_safetensors, write_json

#: open_clip's file names of a model folder's weights and config (``local-dir:`` and the Hugging Face hub).
WEIGHTS_FILE = "open_clip_model.safetensors"
CONFIG_FILE = "open_clip_config.json"
#: The training state a run resumes from (model, optimiser, step, metrics), written atomically.
STATE_FILE = "state.pt"
#: The run's record: its resolved config, steps, times, the probe of random and pretrained weights.
RECORD_FILE = "pretrain.json"
SOURCE = "cliport-pretrain"


def save_open_clip(model: Any, model_name: str, folder: str, steps: int, config: dict[str, Any]) -> str:
    """Write ``model``'s weights and open_clip config into ``folder``; returns the weights file's path.

    The safetensors metadata holds the model name (:data:`~cliport.models.encoders.clip_weights.MODEL_NAME_KEY`),
    ``source`` (cliport-pretrain), ``steps``, the run's ``config`` (JSON) and the cliport version.
    """
    state = {k: v.detach().float().cpu() for k, v in model.state_dict().items()}
    path = os.path.join(folder, WEIGHTS_FILE)
    metadata = {
        MODEL_NAME_KEY: model_name,
        "source": SOURCE,
        "steps": str(steps),
        "config": json.dumps(config),
        "cliport_version": __version__,
    }
    save_safetensors(state, path, metadata)
    preprocess = {"mean": list(model.visual.image_mean), "std": list(model.visual.image_std)}
    preprocess["size"] = model_config(model_name)["vision_cfg"]["image_size"]
    write_json(os.path.join(folder, CONFIG_FILE), {"model_cfg": model_config(model_name), "preprocess_cfg": preprocess})
    return path


def read_open_clip_metadata(path: str) -> dict[str, str]:
    """The string metadata of a weights file written by :func:`save_open_clip`."""
    return load_safetensors(path)[1]


def load_state(path: str) -> dict[str, Any]:
    """A run's saved training state (:data:`STATE_FILE`), read with torch's weights-only loader."""
    from cliport.utils.files import load_torch

    state = load_torch(path)
    if not isinstance(state, dict) or not {"model", "optimizer", "step"} <= set(state):
        from cliport.errors import CheckpointError

        raise CheckpointError(f"{path} is not a cliport-pretrain state (no model, optimizer and step)")
    return state


def state_tensors(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The model's state dict on the CPU (what :data:`STATE_FILE` holds of it)."""
    return {k: v.detach().cpu() for k, v in model.state_dict().items()}
