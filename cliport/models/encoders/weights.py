"""Helpers shared by the frozen encoders' weight loading: state-dict files, architecture checks, calibration.

Each encoder raises its own user-error class (``CLIPWeightsUnavailable``, ``RN50WeightsUnavailable``,
...) with its own wording, so the helpers that report a bad file take ``error``: a function
``(path, reason) -> exception`` that builds the one-line error naming the file, e.g.
``lambda path, reason: MyError(f"Cannot load my weights from {path}: {reason}")``.
"""

from __future__ import annotations

import pickle
import struct
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

import torch
from torch import nn

#: Builds the exception raised for a bad weights file: ``error(path, reason)``.
BadFileError = Callable[[Path, str], Exception]

CALIBRATION_SEED = 0


def first_sentence(err: BaseException, limit: int = 120) -> str:
    """The first sentence of an exception's message (first line, up to the first ". "), at most ``limit`` chars."""
    text = str(err).strip().split("\n")[0].split(". ")[0].rstrip(".")
    return text if len(text) <= limit else text[: limit - 3] + "..."


def load_state_dict_file(
    path: Path, error: BadFileError, wrappers: tuple[str, ...] = ("state_dict",)
) -> dict[str, torch.Tensor]:
    """The tensors of a state-dict file (``.safetensors``, else ``torch.save`` format: ``.pt``/``.pth``/``.bin``).

    Loads with ``weights_only=True`` (never runs code from the file), unwraps a checkpoint that holds the state
    dict under one of ``wrappers`` (``{"state_dict": ...}``; R3M's ``{"r3m": ...}`` where a loader asks for it)
    and strips DataParallel's ``module.`` prefix. Raises ``error(path, reason)`` with a one-line reason if the
    file is empty, truncated, random bytes, a pickled model or not a mapping of named tensors.
    """
    if path.suffix == ".safetensors":
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        try:
            return load_file(str(path))
        except (SafetensorError, OSError) as err:
            raise error(path, f"not a valid safetensors file ({first_sentence(err)})") from None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        # torch's message advises weights_only=False, i.e. running the file's code; never pass that on.
        if zipfile.is_zipfile(path):
            reason = "it holds pickled Python objects besides tensors (a whole model?); save model.state_dict()"
        else:
            reason = "not a PyTorch state-dict file (random or foreign bytes)"
        raise error(path, reason) from None
    except EOFError:
        raise error(path, "the file is empty or truncated") from None
    except (IndexError, KeyError, UnicodeDecodeError, struct.error) as err:
        # The weights-only unpickler reads foreign bytes as opcodes; some fail these ways, not as UnpicklingError.
        if zipfile.is_zipfile(path):
            raise error(path, f"truncated or corrupt checkpoint ({first_sentence(err)})") from None
        raise error(path, "not a PyTorch state-dict file (random or foreign bytes)") from None
    except (RuntimeError, OSError, ValueError) as err:
        if str(err).startswith("Invalid magic number"):  # neither a zip archive nor torch's legacy format
            raise error(path, "not a PyTorch state-dict file (random or foreign bytes)") from None
        raise error(path, f"truncated or corrupt checkpoint ({first_sentence(err)})") from None
    wrapper = next((k for k in wrappers if isinstance(state, Mapping) and isinstance(state.get(k), Mapping)), None)
    if wrapper is not None:
        state = state[wrapper]
    if not isinstance(state, Mapping) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise error(path, f"it holds a {type(state).__name__}, not a state dict of named tensors")
    return {k.removeprefix("module."): v for k, v in state.items()}


def check_architecture(
    path: Path,
    state: Mapping[str, torch.Tensor],
    expected: Mapping[str, torch.Tensor],
    what: str,
    error: BadFileError,
) -> None:
    """Raise ``error(path, reason)`` unless ``state`` has exactly ``expected``'s keys and shapes.

    ``what`` names the expected model in the reason ("not a state dict of <what>: ..."), which counts the
    missing, unexpected and reshaped tensors and gives one example of each.
    """
    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    mismatched = [k for k in expected if k in state and tuple(state[k].shape) != tuple(expected[k].shape)]
    problems = []
    if missing:
        problems.append(f"{len(missing)} of its {len(expected)} tensors missing (e.g. {missing[0]})")
    if unexpected:
        problems.append(f"{len(unexpected)} unexpected (e.g. {unexpected[0]})")
    if mismatched:
        k = mismatched[0]
        shapes = f"{tuple(state[k].shape)} instead of {tuple(expected[k].shape)}"
        problems.append(f"{len(mismatched)} with other shapes (e.g. {k}: {shapes})")
    if problems:
        raise error(path, f"not a state dict of {what}: {'; '.join(problems)}")


def calibrate_batch_norm(
    module: nn.Module,
    run: Callable[[torch.Tensor], object],
    n_images: int = 4,
    size: int = 128,
    seed: int = CALIBRATION_SEED,
) -> None:
    """Set ``module``'s batch-norm statistics from one pass of seeded noise images (random weights only).

    Freshly initialised batch norms hold mean 0 / variance 1, under which a random ResNet's activations
    shrink about a thousandfold by its last stage, so a random "semantic stream" carries almost no
    signal. ``run`` is called once, in training mode and without gradients, on normalised noise
    (n_images, 3, size, size) ~ N(0, 1); with momentum None (a cumulative average) that one batch sets
    every layer's statistics exactly, giving unit-scale inputs as trained weights do. Momentum is then
    reset to 0.1 and ``module`` left in eval mode. Deterministic for a given ``seed``.
    """
    norms = [m for m in module.modules() if isinstance(m, (nn.BatchNorm1d, nn.BatchNorm2d, nn.BatchNorm3d))]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative average: one batch sets the statistics exactly
    generator = torch.Generator().manual_seed(seed)
    images = torch.randn(n_images, 3, size, size, generator=generator)
    module.train()
    with torch.no_grad():
        run(images)
    module.eval()
    for m in norms:
        m.momentum = 0.1
