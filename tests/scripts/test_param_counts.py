import importlib.util
import pathlib

import pytest

SCRIPT = pathlib.Path(__file__).resolve().parents[2] / "scripts" / "param_counts.py"


@pytest.fixture(scope="module")
def param_counts():
    spec = importlib.util.spec_from_file_location("param_counts", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_reference_counts_match_the_published_sizes(param_counts) -> None:
    """DESIGN.md: the reference CLIPort has ~92 M trainable parameters per net, ~277 M in total."""
    two = param_counts.reference_counts("two_stream")
    assert 91.5e6 < two["pick"] < 93e6 and 276e6 < two["trainable_total"] < 278e6
    transporter = param_counts.reference_counts("transporter_only")
    assert 9.7e6 < transporter["pick"] < 9.9e6
    # RN50-BERT is CLIPort's net plus a 768 -> 1024 projection of the sentence feature per net.
    assert param_counts.reference_counts("rn50_bert")["pick"] - two["pick"] == 768 * 1024 + 1024
    assert param_counts.reference_counts("no_such_agent") is None


#: The reference CLIPort's trainable totals, counted from its built modules (frozen CLIP excluded).
REFERENCE_TOTALS = {"transporter_only": 29_470_288, "two_stream": 277_015_435, "clip_only": 155_458_295}


@pytest.mark.parametrize("name", sorted(REFERENCE_TOTALS))
def test_our_nets_have_exactly_the_references_parameters(param_counts, name: str) -> None:
    counts = param_counts.agent_counts(name)
    ref = counts["reference"]
    assert ref["trainable_total"] == REFERENCE_TOTALS[name]
    for net in ("pick", "key", "query", "trainable_total"):
        assert counts[net] == ref[net], net
    if name != "transporter_only":
        assert counts["frozen"] > 100e6  # the one shared CLIP RN50, image and text towers
