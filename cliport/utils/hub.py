"""The Hugging Face Hub as a place runs come from: ``hf://org/name[@revision]`` names and the offline check.

The one place that reads ``HF_HUB_OFFLINE`` and resolves ``hf://`` names, for every layer that needs it:
the frozen encoders' weight loading (:mod:`cliport.models.encoders`), ``from_pretrained``
(:mod:`cliport.agents.checkpoint`) and the commands that read a run (:mod:`cliport.deploy`). Pushing a run to
the Hub is :mod:`cliport.deploy.hub`'s.
"""

from __future__ import annotations

import os
import re
import socket

from cliport.errors import ConfigError, HubError, RunDirError
from cliport.utils import run_dir as layout

HF_PREFIX = "hf://"
HF_HUB_HOST = ("huggingface.co", 443)
_REPO_ID = re.compile(r"[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*")
# What huggingface_hub reads as true in its boolean environment variables (constants.ENV_VARS_TRUE_VALUES).
_TRUE = {"1", "ON", "YES", "TRUE"}


def parse_hub_ref(text: str) -> tuple[str, str | None]:
    """``hf://org/name[@revision]`` -> (``org/name``, revision or None)."""
    ref = text[len(HF_PREFIX) :] if text.startswith(HF_PREFIX) else text
    repo_id, _, revision = ref.partition("@")
    repo_id = repo_id.strip("/")
    if not _REPO_ID.fullmatch(repo_id) or (revision == "" and "@" in ref):
        raise ConfigError(f"a Hub run must look like hf://org/name or hf://org/name@revision, got {text!r}")
    return repo_id, revision or None


def hf_hub_offline() -> bool:
    """Whether the Hugging Face Hub must not be contacted: ``HF_HUB_OFFLINE`` set to a true value (1, on, yes,
    true, as huggingface_hub reads it) now, or when huggingface_hub was imported."""
    if os.environ.get("HF_HUB_OFFLINE", "").upper() in _TRUE:
        return True
    from huggingface_hub import constants

    return bool(constants.HF_HUB_OFFLINE)


def host_reachable(host: str, port: int, timeout_s: float = 3.0) -> bool:
    """Whether ``host:port`` accepts a TCP connection within ``timeout_s`` seconds."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


def hf_hub_reachable(timeout_s: float = 3.0) -> bool:
    """Whether the Hugging Face Hub may be used: not :func:`hf_hub_offline` and huggingface.co:443 answers in
    time."""
    return not hf_hub_offline() and host_reachable(*HF_HUB_HOST, timeout_s=timeout_s)


def one_line(error: BaseException) -> str:
    """An exception as one short line: its type and its message's words, at most 300 characters."""
    text = " ".join(str(error).split())
    return f"{type(error).__name__}: {text[:300]}"


def resolve_run_dir(text: str) -> str:
    """A local run folder for ``--run-dir``: a local path as given, or ``hf://org/name[@revision]`` fetched
    with ``huggingface_hub.snapshot_download`` into the Hugging Face cache (cache only when
    :func:`hf_hub_offline`). One-line errors (RunDirError / HubError) when it cannot be had."""
    if not str(text).startswith(HF_PREFIX):
        return text
    repo_id, revision = parse_hub_ref(text)
    from huggingface_hub import snapshot_download
    from huggingface_hub.errors import LocalEntryNotFoundError, RepositoryNotFoundError, RevisionNotFoundError

    offline = hf_hub_offline()
    rev = f" --revision {revision}" if revision else ""
    try:
        path = snapshot_download(repo_id, revision=revision, local_files_only=offline)
    except LocalEntryNotFoundError:
        why = "HF_HUB_OFFLINE is set" if offline else "the Hub cannot be reached"
        raise RunDirError(
            f"{text} is not in the local Hugging Face cache and {why}: pre-fill the cache on a machine with "
            f"network (same HF_HOME) with `hf download {repo_id}{rev}` (`huggingface-cli download "
            f"{repo_id}{rev}` with huggingface_hub < 1.0), or pass a local run folder to --run-dir"
        ) from None
    except RevisionNotFoundError:
        raise RunDirError(f"{text}: the repo {repo_id} has no revision {revision!r}") from None
    except RepositoryNotFoundError:
        raise RunDirError(
            f"{text}: no repo {repo_id} on the Hugging Face Hub (or it is private: log in with `hf auth login`)"
        ) from None
    except (OSError, ValueError) as e:
        raise HubError(f"could not fetch {text}: {one_line(e)}") from None
    if not layout.RunDir(path).is_run():
        raise RunDirError(f"{text} holds no {layout.CONFIG}: not a cliport run")
    return path


__all__ = [
    "HF_HUB_HOST",
    "HF_PREFIX",
    "hf_hub_offline",
    "hf_hub_reachable",
    "host_reachable",
    "one_line",
    "parse_hub_ref",
    "resolve_run_dir",
]
