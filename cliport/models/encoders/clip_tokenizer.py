"""The frozen open_clip model's tokenizer: instructions to tokens, and how many tokens an instruction has.

Text: the model's own tokenizer (``open_clip.get_tokenizer(name)``) and its context length (77 for the
OpenAI-style models, other values elsewhere). open_clip ships the CLIP BPE tokenizer inside the package;
models whose tokenizer is a Hugging Face one (the SigLIP family, ``*-CLIPA``, ``*-worldwide``,
``roberta-*``, ``xlm-roberta-*``, ``mt5-*``, ``nllb-*``) fetch it from the Hugging Face hub, and the
HF-text-tower models also their text tower's config. Offline they therefore need a Hugging Face cache
(``HF_HOME``) filled on a machine with network; without one, loading fails with one line,
:class:`TokenizerUnavailable`, before any weights are fetched. (SigLIP models are refused for their timm
image tower in any case, see :mod:`cliport.models.encoders.clip_registry`.)
"""

from __future__ import annotations

import functools
from typing import Any

from cliport.errors import UserError
from cliport.models.encoders import weights
from cliport.models.encoders.clip_registry import MODEL_NAME, import_open_clip, quiet_open_clip

# The default model reads at most this many tokens of an instruction, start and end tokens included; the
# tokenizer cuts the rest off without saying so. Other models: FrozenCLIP.context_length.
CONTEXT_LENGTH = 77


class TokenizerUnavailable(UserError, RuntimeError):
    """The model's tokenizer (or its Hugging Face text tower's config) cannot be fetched."""


@functools.cache
def load_tokenizer(model_name: str = MODEL_NAME) -> Any:
    """The model's tokenizer; :class:`TokenizerUnavailable` in one line when it cannot be fetched."""
    open_clip = import_open_clip()
    with quiet_open_clip():
        try:
            return open_clip.get_tokenizer(model_name)
        except Exception as err:  # transformers/huggingface_hub raise OSError, ValueError, ... offline
            raise TokenizerUnavailable(
                f"Cannot load the tokenizer of {model_name}: it comes from the Hugging Face hub, which is "
                f"unreachable and not in the local cache (HF_HOME) ({weights.first_sentence(err)}); fill the cache "
                "on a machine with network, or choose a model with open_clip's own tokenizer (e.g. RN50-quickgelu)"
            ) from None


def count_tokens(tokenizer: Any, text: str) -> int:
    """Tokens of ``text`` with the model's special tokens (CLIP BPE: start and end)."""
    if hasattr(tokenizer, "encode"):  # open_clip's SimpleTokenizer
        return len(tokenizer.encode(text)) + 2  # + start and end tokens
    return len(tokenizer.tokenizer(text)["input_ids"])  # a wrapped Hugging Face tokenizer adds its own


def instruction_token_count(text: str, model_name: str = MODEL_NAME) -> int:
    """Tokens of an instruction for ``model_name``, special tokens included; the default reads
    :data:`CONTEXT_LENGTH`, others :attr:`FrozenCLIP.context_length`."""
    return count_tokens(load_tokenizer(model_name), text)
