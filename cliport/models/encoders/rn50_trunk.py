"""The image trunk of CLIPort's RN50-BERT ablation: torchvision's ResNet-50 without its classifier head.

The architecture is torchvision's ResNet-50; the five levels are the stem (conv1, bn1, relu, maxpool;
64 channels, stride 4) and layer1..layer4 (256, 512, 1024, 2048 channels at strides 4, 8, 16, 32). Its
classifier head (``avgpool``, ``fc``) is dropped.

Weight sources (``rn50_weights`` in the agent configs):

- ``"imagenet"``: torchvision's ``ResNet50_Weights.IMAGENET1K_V1`` (what CLIPort's
  ``resnet50(pretrained=True)`` loaded), taken from torch's hub cache
  (``torch.hub.get_dir()/checkpoints/``) when present, otherwise downloaded from download.pytorch.org.
  Without network this fails within seconds with :class:`RN50WeightsUnavailable`, which lists the
  offline options.
- a path to a local file: a state dict of torchvision's ``resnet50`` (``.pt``/``.pth``/``.bin`` or
  ``.safetensors``). The classifier's ``fc.*`` tensors may be present and are ignored (the head is not
  used); every other tensor must be there with its shape. Batch norms' ``num_batches_tracked``
  counters, absent from some older files, may be missing (they play no part in eval mode).
- R3M's ResNet-50 (``~/.r3m/r3m_50/model.pt`` as R3M's ``load_r3m("resnet50")`` downloads it): a dict holding,
  under ``"r3m"``, the state dict of its DataParallel-wrapped model, whose ``module.convnet.*`` tensors are a
  torchvision ``resnet50`` without ``fc`` (R3M normalises images with ImageNet's statistics, as this trunk's
  encoder does); its language head (``module.lang_enc.*``, ``module.lang_rew.*``) is not used.
- ``"random"``: a seeded (seed 0) random initialisation whose batch-norm statistics are calibrated
  on noise so that its features keep unit scale (tests and benchmarks only).

A failed load never falls back to ``"random"``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import torch
from torch import nn

from cliport.errors import UserError
from cliport.models.encoders import weights
from cliport.utils import hub

RANDOM_SEED = 0
_TORCHVISION_HOST = ("download.pytorch.org", 443)
_RESNET_WHAT = "torchvision resnet50 (fc.* ignored)"


class RN50WeightsUnavailable(UserError, RuntimeError):
    """The requested ResNet-50 weights could not be loaded."""


class ResNet50Trunk(nn.Module):
    """torchvision's ResNet-50 without its classifier head, returning the five trunk levels.

    Submodule names are torchvision's (``conv1``, ``bn1``, ``layer1`` ...), so its state dict is a
    torchvision ``resnet50`` state dict without the ``fc.*`` tensors.
    """

    def __init__(self, resnet: Any) -> None:  # a torchvision ResNet (torchvision here has no type information)
        super().__init__()
        self.conv1 = resnet.conv1
        self.bn1 = resnet.bn1
        self.relu = resnet.relu
        self.maxpool = resnet.maxpool
        self.layer1 = resnet.layer1
        self.layer2 = resnet.layer2
        self.layer3 = resnet.layer3
        self.layer4 = resnet.layer4

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Normalised images (N, 3, H, W) -> [(N, 64, H/4, W/4), (N, 256, H/4, W/4), (N, 512, H/8, W/8),
        (N, 1024, H/16, W/16), (N, 2048, H/32, W/32)]."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        levels = [x]
        for layer in (self.layer1, self.layer2, self.layer3, self.layer4):
            x = layer(x)
            levels.append(x)
        return levels


def _bad_rn50_file(path: Path, reason: str) -> RN50WeightsUnavailable:
    return RN50WeightsUnavailable(f"Cannot load RN50 weights from {path}: {reason}")


def _imagenet_weights() -> Any:
    from torchvision.models import ResNet50_Weights

    return ResNet50_Weights.IMAGENET1K_V1


def imagenet_cache_file() -> Path:
    """Where torch's hub cache keeps torchvision's ImageNet ResNet-50 weights (the file may not exist)."""
    name = os.path.basename(urlparse(_imagenet_weights().url).path)
    return Path(torch.hub.get_dir()) / "checkpoints" / name


def _download_reachable(timeout_s: float = 3.0) -> bool:
    """Whether download.pytorch.org answers a TCP connection within `timeout_s` seconds."""
    return hub.host_reachable(*_TORCHVISION_HOST, timeout_s=timeout_s)


def _rn50_offline_help(source: str, reason: str) -> str:
    url = _imagenet_weights().url
    return (
        f"Cannot load RN50 weights '{source}': {reason}\n"
        "Options without network:\n"
        f"  * copy {url} (downloaded on a machine with network) to {imagenet_cache_file()};\n"
        "  * copy a torchvision resnet50 state dict (.pt/.pth/.bin/.safetensors) to this machine and set "
        "rn50_weights = '/path/to/file';\n"
        "  * for tests and benchmarks only, set rn50_weights = 'random' (seeded random initialisation)."
    )


def _resnet50() -> nn.Module:
    """torchvision's resnet50, seeded (seed 0) without touching the caller's random state."""
    from torchvision.models import resnet50

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(RANDOM_SEED)
        return resnet50(weights=None)


def _load_trunk_state(trunk: ResNet50Trunk, path: Path, state: Mapping[str, torch.Tensor]) -> ResNet50Trunk:
    """Load a torchvision resnet50 state dict into ``trunk`` strictly (``fc.*`` dropped); errors name ``path``."""
    expected = trunk.state_dict()
    state = {k: v for k, v in state.items() if not k.startswith("fc.")}
    counters = [k for k in expected if k.endswith(".num_batches_tracked")]
    if not any(k in state for k in counters):
        state.update({k: expected[k] for k in counters})
    weights.check_architecture(path, state, expected, _RESNET_WHAT, _bad_rn50_file)
    trunk.load_state_dict(state, strict=True)
    return trunk


def build_rn50_trunk(source: str) -> ResNet50Trunk:
    """The ResNet-50 trunk with weights from ``source`` ("imagenet", a state-dict file, or "random").

    Returned in eval mode; raises :class:`RN50WeightsUnavailable` (one line naming the file for a bad
    file, the offline options when "imagenet" cannot be had).
    """
    if source == "random":
        trunk = ResNet50Trunk(_resnet50())
        weights.calibrate_batch_norm(trunk, trunk, seed=RANDOM_SEED)
        return trunk.eval()
    if source == "imagenet":
        cached = imagenet_cache_file()
        if cached.is_file():
            return _load_trunk_state(
                ResNet50Trunk(_resnet50()), cached, weights.load_state_dict_file(cached, _bad_rn50_file)
            ).eval()
        if not _download_reachable():
            raise RN50WeightsUnavailable(
                _rn50_offline_help(
                    source, f"the weights are not cached at {cached} and download.pytorch.org is unreachable."
                )
            )
        try:
            state = _imagenet_weights().get_state_dict(progress=False)
        except Exception as err:  # urllib, hash checks and torch.load raise assorted errors for a failed download
            raise RN50WeightsUnavailable(_rn50_offline_help(source, weights.first_sentence(err) + ".")) from err
        return _load_trunk_state(ResNet50Trunk(_resnet50()), cached, state).eval()
    path = Path(source).expanduser()
    if not path.is_file():
        raise RN50WeightsUnavailable(
            _rn50_offline_help(source, "it is neither 'imagenet', 'random' nor an existing file.")
        )
    state = r3m_convnet(weights.load_state_dict_file(path, _bad_rn50_file, wrappers=("state_dict", "r3m")))
    return _load_trunk_state(ResNet50Trunk(_resnet50()), path, state).eval()


#: The prefix of R3M's visual encoder in its checkpoints (after DataParallel's ``module.``, which the file loader
#: strips): ``convnet.conv1.weight``, ...
R3M_CONVNET = "convnet."


def r3m_convnet(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """An R3M checkpoint's visual encoder as a torchvision state dict (its ``convnet.*`` tensors, prefix stripped);
    any other state dict as it is."""
    if not any(k.startswith(R3M_CONVNET) for k in state):
        return state
    return {k.removeprefix(R3M_CONVNET): v for k, v in state.items() if k.startswith(R3M_CONVNET)}
