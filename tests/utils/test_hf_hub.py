"""hf:// names and the one HF_HUB_OFFLINE check that the encoders, from_pretrained and the commands share
(resolving a cached run end to end is tests/deploy/test_hub.py's)."""

from __future__ import annotations

import pytest

from cliport.errors import ConfigError
from cliport.utils import hub


@pytest.mark.parametrize(
    ("value", "offline"),
    [("1", True), ("true", True), ("ON", True), ("yes", True), ("0", False), ("", False), ("false", False)],
)
def test_offline_reads_hf_hub_offline_as_huggingface_hub_does(monkeypatch, value, offline):
    from huggingface_hub import constants

    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", False)
    monkeypatch.setenv("HF_HUB_OFFLINE", value)
    assert hub.hf_hub_offline() is offline
    monkeypatch.setattr(hub, "host_reachable", lambda *a, **k: True)
    assert hub.hf_hub_reachable() is not offline


def test_offline_when_huggingface_hub_was_imported_offline(monkeypatch):
    from huggingface_hub import constants

    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", True)
    assert hub.hf_hub_offline()


def test_hub_refs():
    assert hub.parse_hub_ref("hf://org/name") == ("org/name", None)
    assert hub.parse_hub_ref("hf://org/name@v1.0") == ("org/name", "v1.0")
    for bad in ("hf://name", "hf://org/name@", "hf:///org"):
        with pytest.raises(ConfigError, match="hf://org/name"):
            hub.parse_hub_ref(bad)
    assert hub.resolve_run_dir("runs/local") == "runs/local"  # a local path as given, no Hub call
