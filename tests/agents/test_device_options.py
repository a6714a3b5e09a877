"""The CUDA speed settings' CPU-checkable parts: the bf16 trunk is reversible, and nothing applies on a CPU."""

from __future__ import annotations

import pytest
import torch

from cliport.agents import make_agent
from cliport.errors import ConfigError
from cliport.utils.device import bf16_native, resolve_device


@pytest.fixture(scope="module")
def two_stream_overrides() -> dict[str, object]:
    """This module's ``two_stream`` agent (tests/agents/conftest.py) has 4 rotations."""
    return {"n_rotations": 4}


def _trunk_state(agent) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in agent.encoder.image_module().state_dict().items()}


def test_bf16_trunk_comes_back_as_the_float32_weights(two_stream) -> None:
    encoder = two_stream.encoder
    original = _trunk_state(two_stream)
    rounded = {k: v.to(torch.bfloat16).to(v.dtype) for k, v in original.items()}
    assert any(not torch.equal(rounded[k], original[k]) for k in original)  # what a plain round trip loses

    encoder.set_image_dtype(torch.bfloat16)
    assert encoder.image_dtype() == torch.bfloat16
    assert next(encoder.model.transformer.parameters()).dtype == torch.float32  # the text side never changes
    encoder.set_image_dtype(torch.float32)
    restored = _trunk_state(two_stream)
    assert all(torch.equal(restored[k], original[k]) for k in original)

    # A float32 cast by other means (agent.float()) while in bf16 still ends at the exact weights.
    encoder.set_image_dtype(torch.bfloat16)
    two_stream.float()
    encoder.set_image_dtype(torch.float32)
    assert all(torch.equal(_trunk_state(two_stream)[k], original[k]) for k in original)


def test_weights_loaded_into_a_bf16_trunk_are_kept_at_full_precision(two_stream) -> None:
    encoder = two_stream.encoder
    original = _trunk_state(two_stream)
    replacement = {k: v * 1.001 if v.is_floating_point() else v for k, v in original.items()}
    name = next(n for n, m in two_stream.named_modules() if m is encoder.image_module())
    encoder.set_image_dtype(torch.bfloat16)
    two_stream.load_state_dict({f"{name}.{k}": v for k, v in replacement.items()}, strict=False)
    encoder.set_image_dtype(torch.float32)
    assert all(torch.equal(_trunk_state(two_stream)[k], replacement[k]) for k in original)
    two_stream.encoder.image_module().load_state_dict(original)


def test_only_fused_adam_applies_on_a_cpu(tiny_config) -> None:
    agent = make_agent("transporter_only", tiny_config("transporter_only", n_rotations=4))
    assert all(agent.device_options.values())  # asked for
    active = agent.active_device_options()
    assert active.pop("fused_adam") and not any(active.values())
    assert not bf16_native(torch.device("cpu"))


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message of a machine without CUDA")
def test_a_cuda_device_without_cuda_is_one_line() -> None:
    with pytest.raises(ConfigError, match="CUDA is not available"):
        resolve_device("cuda:1")
