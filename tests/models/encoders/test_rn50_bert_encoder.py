import json
import logging
import os
import shutil
import time
import warnings
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from cliport.errors import UserError
from cliport.models.encoders import distilbert, rn50_bert_encoder, rn50_trunk
from cliport.models.encoders.distilbert import BERTWeightsUnavailable, HashingTokenizer, build_distilbert
from cliport.models.encoders.rn50_bert_encoder import MAX_TOKENS, FrozenRN50BERT, load_rn50_bert
from cliport.models.encoders.rn50_trunk import RN50WeightsUnavailable, build_rn50_trunk, imagenet_cache_file

VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", "pack", "push", "the", "box", "pile", "red", "block", ",", "."]


@pytest.fixture(scope="module")
def encoder() -> FrozenRN50BERT:
    return load_rn50_bert("random", "random")


def _perturbed_resnet_state(encoder: FrozenRN50BERT) -> dict[str, torch.Tensor]:
    """A full torchvision resnet50 state dict (fc.* included) that differs from the seeded random init."""
    gen = torch.Generator().manual_seed(123)
    state = {
        k: (v + torch.randn(v.shape, generator=gen).to(v.dtype) if v.is_floating_point() else v).contiguous()
        for k, v in encoder.trunk.state_dict().items()
    }
    state["fc.weight"] = torch.zeros(1000, 2048)
    state["fc.bias"] = torch.zeros(1000)
    return state


def _assert_trunk_holds(trunk: torch.nn.Module, state: dict[str, torch.Tensor]) -> None:
    got = trunk.state_dict()
    expected = {k: v for k, v in state.items() if not k.startswith("fc.")}
    assert {k for k in got if k not in expected} <= {k for k in got if k.endswith(".num_batches_tracked")}
    for k, v in expected.items():
        assert torch.equal(got[k], v), k


def _bert_folder(root: Path, head: bool = False) -> Path:
    """A save_pretrained folder of a small random DistilBERT (or DistilBertForMaskedLM) and its tokenizer."""
    from transformers import DistilBertConfig, DistilBertForMaskedLM, DistilBertModel, DistilBertTokenizerFast

    folder = root / ("bert-mlm" if head else "bert")
    folder.mkdir()
    (folder / "vocab.txt").write_text("\n".join(VOCAB) + "\n")
    tokenizer = DistilBertTokenizerFast.from_pretrained(str(folder), model_max_length=512)  # as distilbert's
    config = DistilBertConfig(vocab_size=len(VOCAB), dim=32, n_layers=2, n_heads=2, hidden_dim=64)
    torch.manual_seed(7)
    model = (DistilBertForMaskedLM if head else DistilBertModel)(config)
    model.save_pretrained(str(folder))
    tokenizer.save_pretrained(str(folder))
    return folder


@pytest.fixture(scope="module")
def bert_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _bert_folder(tmp_path_factory.mktemp("bert"))


# ---------------------------------------------------------------------------------------------- features


def test_image_features_shapes(encoder: FrozenRN50BERT) -> None:
    feats = encoder.image_features(torch.rand(2, 3, 64, 96))
    shapes = [tuple(f.shape) for f in feats]
    assert shapes == [(2, 64, 16, 24), (2, 256, 16, 24), (2, 512, 8, 12), (2, 1024, 4, 6), (2, 2048, 2, 3)]
    assert [s[1] for s in shapes] == list(encoder.trunk_channels)
    assert not any(f.requires_grad for f in feats)
    assert all(f.dtype == torch.float32 for f in feats)


def test_random_trunk_features_are_unit_scale(encoder: FrozenRN50BERT) -> None:
    """Calibrated batch norms: the random trunk's features do not vanish with depth."""
    feats = encoder.image_features(torch.rand(2, 3, 64, 96, generator=torch.Generator().manual_seed(1)))
    scales = [f.abs().mean().item() for f in feats]
    assert all(0.1 < s < 10 for s in scales), scales
    norms = [m for m in encoder.trunk.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert norms and all(m.momentum == 0.1 and not m.training for m in norms)


def test_imagenet_normalisation(encoder: FrozenRN50BERT) -> None:
    assert torch.allclose(encoder.mean.flatten(), torch.tensor([0.485, 0.456, 0.406]))
    assert torch.allclose(encoder.std.flatten(), torch.tensor([0.229, 0.224, 0.225]))


def test_sentence_features_are_cached_per_string(encoder: FrozenRN50BERT) -> None:
    feats = encoder.sentence_features(["pack the box", "push the pile", "pack the box"])
    assert feats.shape == (3, 768) and feats.dtype == torch.float32 and not feats.requires_grad
    assert torch.equal(feats[0], feats[2])
    assert not torch.allclose(feats[0], feats[1])
    assert "pack the box" in encoder._sentence_cache


def test_padding_does_not_change_a_sentence(encoder: FrozenRN50BERT) -> None:
    short, long = "pack it", "put the red block in the green bowl, then push the pile of blue blocks into the zone"
    together = encoder._encode_sentences([short, long])
    alone = torch.cat([encoder._encode_sentences([short]), encoder._encode_sentences([long])])
    assert torch.allclose(together, alone, atol=1e-5, rtol=0), (together - alone).abs().max()


def test_encoder_declares_its_widths_and_sources(encoder: FrozenRN50BERT) -> None:
    assert encoder.trunk_channels == (64, 256, 512, 1024, 2048)
    assert encoder.sentence_dim == 768 and encoder.sentence_projection == 1024
    assert encoder.sources() == {"rn50_weights": "random", "bert_weights": "random"}
    assert encoder.image_module() is encoder.trunk
    assert not hasattr(encoder.trunk, "fc") and not hasattr(encoder.trunk, "avgpool")


def test_long_instruction_note(encoder: FrozenRN50BERT) -> None:
    assert encoder.instruction_note("pack the box") is None
    note = encoder.instruction_note("red " * 600)
    assert note is not None and "602" in note and str(MAX_TOKENS) in note


def test_hashing_tokenizer() -> None:
    tok = HashingTokenizer()
    one = tok("Pack the box, RED!")
    assert one["input_ids"][0] == 101 and one["input_ids"][-1] == 102 and len(one["input_ids"]) == 8
    assert one["input_ids"] == tok("pack the box , red !")["input_ids"]
    assert all(1000 <= i < 30522 for i in one["input_ids"][1:-1])
    batch = tok(["pack", "red " * 600], padding=True, truncation=True, max_length=512, return_tensors="pt")
    assert batch["input_ids"].shape == (2, 512) and batch["input_ids"][1, -1] == 102
    assert batch["attention_mask"][0].sum() == 3 and batch["input_ids"][0, 3:].eq(0).all()


# ---------------------------------------------------------------------------------------------- frozen


def test_frozen_stays_in_eval_mode_without_grads(encoder: FrozenRN50BERT) -> None:
    encoder.train()
    assert not encoder.training and not any(m.training for m in encoder.modules())
    assert not any(p.requires_grad for p in encoder.parameters())


def test_random_init_is_reproducible_and_quiet(
    encoder: FrozenRN50BERT, caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    torch.manual_seed(999)  # the global seed must not matter
    capfd.readouterr()
    with caplog.at_level(logging.DEBUG), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = load_rn50_bert("random", "random")
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.INFO] == []
    assert [str(w.message) for w in caught] == []
    assert capfd.readouterr() == ("", "")
    pairs = list(zip(encoder.state_dict().items(), again.state_dict().values(), strict=True))
    assert len(pairs) > 100
    for (k, v), w in pairs:
        assert torch.equal(v, w), k


def test_import_is_cheap() -> None:
    import subprocess
    import sys

    code = (
        "import sys, cliport.models.encoders.rn50_bert_encoder; "
        "print('transformers' in sys.modules, 'torchvision' in sys.modules)"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(rn50_bert_encoder.__file__).parents[3])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.split() == ["False", "False"]


# ---------------------------------------------------------------------------------------------- RN50 files


@pytest.mark.parametrize("where", [".pt", ".safetensors", "imagenet-cache"])
def test_resnet_state_dict_round_trip(
    encoder: FrozenRN50BERT, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    state = _perturbed_resnet_state(encoder)
    if where == ".safetensors":
        path = tmp_path / "resnet50.safetensors"
        save_file(state, str(path))
        source = str(path)
    else:
        if where == "imagenet-cache":
            # torchvision's cache file, as older files hold it: no num_batches_tracked counters.
            monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
            monkeypatch.setattr(rn50_trunk, "_download_reachable", lambda timeout_s=3.0: pytest.fail("no download"))
            path = imagenet_cache_file()
            path.parent.mkdir(parents=True)
            state = {k: v for k, v in state.items() if not k.endswith("num_batches_tracked")}
            source = "imagenet"
        else:
            path = tmp_path / "resnet50.pt"
            source = str(path)
        torch.save(state, path)
    trunk = build_rn50_trunk(source)
    _assert_trunk_holds(trunk, state)
    assert not trunk.training


@pytest.mark.parametrize("download", ["works", "fails"])
def test_imagenet_download_path(
    encoder: FrozenRN50BERT, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, download: str
) -> None:
    """Not cached, host reachable: torchvision's download is used, checked, and its failure is a user error."""
    state = _perturbed_resnet_state(encoder)

    class FakeWeights:
        url = "https://download.pytorch.org/models/resnet50-0676ba61.pth"

        def get_state_dict(self, progress: bool = True) -> dict[str, torch.Tensor]:
            assert progress is False
            if download == "fails":
                raise OSError("HTTP Error 503: Service Unavailable. Try again later")
            return state

    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setattr(rn50_trunk, "_download_reachable", lambda timeout_s=3.0: True)
    monkeypatch.setattr(rn50_trunk, "_imagenet_weights", FakeWeights)
    if download == "works":
        _assert_trunk_holds(build_rn50_trunk("imagenet"), state)
        return
    with pytest.raises(RN50WeightsUnavailable) as err:
        build_rn50_trunk("imagenet")
    assert "HTTP Error 503" in str(err.value) and "rn50_weights = 'random'" in str(err.value)


def test_loading_a_file_leaves_the_global_random_state_alone(encoder: FrozenRN50BERT, tmp_path: Path) -> None:
    path = tmp_path / "resnet50.pt"
    torch.save(encoder.trunk.state_dict(), path)
    before = torch.random.get_rng_state()
    build_rn50_trunk(str(path))
    assert torch.equal(torch.random.get_rng_state(), before)


def test_imagenet_fails_fast_and_clearly_offline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "empty-hub"))
    monkeypatch.setattr(rn50_trunk, "_download_reachable", lambda timeout_s=3.0: False)
    start = time.monotonic()
    with pytest.raises(RN50WeightsUnavailable) as err:
        load_rn50_bert("imagenet", "random")
    assert time.monotonic() - start < 10
    message = str(err.value)
    assert "rn50_weights" in message and "random" in message and str(imagenet_cache_file()) in message
    assert isinstance(err.value, UserError) and isinstance(err.value, RuntimeError)


def _bad_resnet_file(tmp_path: Path, kind: str, encoder: FrozenRN50BERT) -> tuple[Path, str]:
    """A state dict of another model, or the trunk's with one wrong shape, and a phrase its error must contain."""
    if kind == "other-model":
        path = tmp_path / "resnet50.safetensors"
        save_file(torch.nn.Linear(2, 2).state_dict(), str(path))
        return path, "missing (e.g. conv1.weight)"
    assert kind == "wrong-shape"  # e.g. a resnet101's or a resnet18's layer
    state = dict(encoder.trunk.state_dict())
    state["layer4.0.conv2.weight"] = torch.zeros(512, 512, 1, 1)
    path = tmp_path / "resnet50.pt"
    torch.save(state, path)
    return path, "layer4.0.conv2.weight: (512, 512, 1, 1) instead of (512, 512, 3, 3)"


@pytest.mark.parametrize(
    "kind",
    [
        *("random-bytes", "truncated", "empty", "fake-safetensors", "pickled-module", "not-a-dict"),
        *("other-model", "wrong-shape"),
    ],
)
def test_bad_resnet_file_is_one_clear_line(encoder: FrozenRN50BERT, tmp_path: Path, kind: str, bad_weight_file) -> None:
    path, reason = bad_weight_file(kind, "resnet50") or _bad_resnet_file(tmp_path, kind, encoder)
    with pytest.raises(RN50WeightsUnavailable) as err:
        build_rn50_trunk(str(path))
    message = str(err.value)
    assert str(path) in message and reason in message, message
    assert "\n" not in message and "weights_only" not in message and len(message) < 300, message


def test_missing_resnet_file_is_an_error_not_a_fallback(tmp_path: Path) -> None:
    path = tmp_path / "nope.pt"
    with pytest.raises(RN50WeightsUnavailable) as err:
        build_rn50_trunk(str(path))
    assert str(path) in str(err.value) and "existing file" in str(err.value)


# ---------------------------------------------------------------------------------------------- BERT folders


def test_bert_folder_loads_and_encodes(bert_folder: Path, encoder: FrozenRN50BERT) -> None:
    from transformers import DistilBertModel

    model, tokenizer = build_distilbert(str(bert_folder))
    saved = DistilBertModel.from_pretrained(str(bert_folder))
    for (k, v), w in zip(model.state_dict().items(), saved.state_dict().values(), strict=True):
        assert torch.equal(v, w), k
    assert tokenizer("pack the box")["input_ids"] == [2, 5, 7, 8, 3]  # the folder's vocab.txt, not hashing
    enc = FrozenRN50BERT(encoder.trunk, model, tokenizer, "random", str(bert_folder))
    assert enc.sources()["bert_weights"] == str(bert_folder)
    feats = enc.sentence_features(["pack the box", "push the red pile ."])
    assert feats.shape == (2, 32) and not torch.allclose(feats[0], feats[1])
    together = enc._encode_sentences(["pack", "push the red pile , pack the box ."])
    alone = torch.cat([enc._encode_sentences(["pack"]), enc._encode_sentences(["push the red pile , pack the box ."])])
    assert torch.allclose(together, alone, atol=1e-5, rtol=0)


def test_long_instruction_with_a_real_tokenizer(
    bert_folder: Path, encoder: FrozenRN50BERT, caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    """Only this module's one warning: not transformers' own "Token indices sequence length" one."""
    model, tokenizer = build_distilbert(str(bert_folder))
    enc = FrozenRN50BERT(encoder.trunk, model, tokenizer, "random", str(bert_folder))
    long = "pack the " + "red " * 600 + "box"
    assert enc.count_tokens(long) == 605 and "605 DistilBERT tokens" in (enc.instruction_note(long) or "")
    capfd.readouterr()
    with caplog.at_level(logging.WARNING):
        feats = enc.sentence_features([long, "pack the box"])
        enc._sentence_cache.clear()  # encoding it again must not repeat the warning
        enc.sentence_features([long])
    assert feats.shape == (2, 32) and torch.isfinite(feats).all()
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "605 DistilBERT tokens" in warned[0], warned
    assert capfd.readouterr().err == ""  # transformers logs to its own stderr handler, not through caplog


def test_masked_lm_checkpoint_loads_quietly(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    """distilbert-base-uncased is a DistilBertForMaskedLM checkpoint: its head is dropped without a report."""
    folder = _bert_folder(tmp_path, head=True)
    capfd.readouterr()
    with caplog.at_level(logging.DEBUG), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model, _ = build_distilbert(str(folder))
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []
    assert [str(w.message) for w in caught] == []
    out, err = capfd.readouterr()
    assert out == "" and err == "", err
    assert not any(k.startswith("vocab_") for k in model.state_dict())


def test_cached_hub_model_is_read_from_the_cache(
    bert_folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from huggingface_hub import constants

    cache = tmp_path / "hub"
    snapshot = cache / "models--someone--tiny-distilbert" / "snapshots" / "0123abcd"
    shutil.copytree(bert_folder, snapshot)
    (cache / "models--someone--tiny-distilbert" / "refs").mkdir()
    (cache / "models--someone--tiny-distilbert" / "refs" / "main").write_text("0123abcd")
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(cache))
    monkeypatch.setattr(distilbert, "_hub_reachable", lambda timeout_s=3.0: pytest.fail("the cache must be enough"))
    model, tokenizer = build_distilbert("someone/tiny-distilbert")
    assert model.config.dim == 32 and tokenizer("pack")["input_ids"] == [2, 5, 3]


@pytest.mark.parametrize("how", ["HF_HUB_OFFLINE", "unreachable"])
def test_hub_bert_fails_fast_and_clearly_offline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str) -> None:
    from huggingface_hub import constants

    monkeypatch.setenv("HF_HOME", str(tmp_path))
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "hub"))
    if how == "HF_HUB_OFFLINE":
        monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    else:
        monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
        monkeypatch.setattr(distilbert, "_hub_reachable", lambda timeout_s=3.0: False)
    start = time.monotonic()
    with pytest.raises(BERTWeightsUnavailable) as err:
        build_distilbert("distilbert-base-uncased")
    assert time.monotonic() - start < 10
    message = str(err.value)
    assert "bert_weights" in message and "random" in message and str(tmp_path / "hub") in message
    assert "distilbert-base-uncased" in message
    assert isinstance(err.value, UserError) and isinstance(err.value, RuntimeError)


def _bad_bert_folder(tmp_path: Path, bert_folder: Path, kind: str) -> tuple[Path, str]:
    """A bad bert_weights folder of the given kind and a phrase its error message must contain."""
    folder = tmp_path / "bert"
    if kind == "missing":
        return folder, "no such folder"
    if kind == "a-file":
        folder.write_bytes(b"x")
        return folder, "a file"
    if kind == "empty":
        folder.mkdir()
        return folder, "missing config.json, the weights (model.safetensors or pytorch_model.bin), the tokenizer's"
    shutil.copytree(bert_folder, folder)
    if kind == "no-vocab":
        for name in ("vocab.txt", "tokenizer.json"):
            (folder / name).unlink(missing_ok=True)
        return folder, "missing the tokenizer's vocab.txt"
    if kind == "no-weights":
        (folder / "model.safetensors").unlink()
        return folder, "missing the weights"
    if kind == "garbage-weights":
        (folder / "model.safetensors").write_bytes(os.urandom(4096))
        return folder, "not a loadable DistilBERT checkpoint"
    if kind == "garbage-config":
        (folder / "config.json").write_bytes(os.urandom(64))
        return folder, "config.json is not a JSON object"
    config = json.loads((folder / "config.json").read_text())
    if kind == "other-model":
        config["model_type"] = "bert"
        (folder / "config.json").write_text(json.dumps(config))
        return folder, "a 'bert' model, not a DistilBERT one"
    assert kind == "missing-layers"
    config["n_layers"] = 3
    (folder / "config.json").write_text(json.dumps(config))
    return folder, "tensors missing (e.g. transformer.layer.2."


@pytest.mark.parametrize(
    "kind",
    [
        "missing",
        "a-file",
        "empty",
        "no-vocab",
        "no-weights",
        "garbage-weights",
        "garbage-config",
        "other-model",
        "missing-layers",
    ],
)
def test_bad_bert_folder_is_one_clear_line(bert_folder: Path, tmp_path: Path, kind: str) -> None:
    folder, reason = _bad_bert_folder(tmp_path, bert_folder, kind)
    with pytest.raises(BERTWeightsUnavailable) as err:
        build_distilbert(str(folder))
    message = str(err.value)
    assert str(folder) in message and reason in message, message
    assert "\n" not in message and "Traceback" not in message and len(message) < 300, message
