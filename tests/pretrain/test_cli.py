"""cliport-pretrain: bad input is one ``error:`` line and exit status 2; ``--probe`` prints the probe as JSON."""

from __future__ import annotations

import json

import pytest
import torch

from cliport.cli.common import run_cli
from cliport.cli.pretrain import main


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as caught:
        run_cli(lambda: main(argv))
        raise SystemExit(0)
    out = capsys.readouterr()
    return int(caught.value.code or 0), out.out, out.err


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--semantic-encoder", "RN5O-quickgelu"], "unknown semantic encoder"),
        (["--steps", "0"], "steps must be at least 1"),
        (["--device", "tpu"], "device must be one of cpu, cuda"),
        (["--batch-size", "many"], "invalid int value"),
        (["--renderer", "gpu"], "renderer must be auto, egl or cpu"),
        (["--probe", "/no/such/weights.safetensors"], "nor an existing file"),
    ],
)
def test_bad_input_is_one_error_line(argv: list[str], says: str, capsys, tmp_path) -> None:
    code, _, err = _run([*argv, "--out-dir", str(tmp_path / "out"), "--cache-dir", str(tmp_path / "crops")], capsys)
    assert code == 2 and err.startswith("error: ") and says in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is present here")
def test_cuda_without_cuda_is_one_error_line(capsys, tmp_path) -> None:
    code, _, err = _run(["--device", "cuda", "--probe", "random", "--cache-dir", str(tmp_path)], capsys)
    assert code == 2 and "no CUDA device" in err and len(err.strip().splitlines()) == 1


def test_probe_prints_json(tiny_cache: str, capsys) -> None:
    argv = ["--probe", "random", "--cache-dir", tiny_cache, "--probe-scenes", "3", "--renderer", "cpu", "--no-progress"]
    code, out, _ = _run(argv, capsys)
    result = json.loads(out)
    assert code == 0 and result["weights"] == "random" and result["semantic_encoder"] == "cliport-RN-tiny"
    assert {"colors", "bowl_colors", "shapes"} <= set(result)
