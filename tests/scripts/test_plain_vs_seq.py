import json
import subprocess
import sys
from pathlib import Path

from cliport.study import summarise_run

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "plain_vs_seq.py"


def _study(folder: Path, task: str, agent: str, test: dict[str, float]) -> Path:
    run = summarise_run(task, agent, 100, test, {}, "ravens")
    folder.mkdir()
    (folder / "combined.json").write_text(json.dumps({"tasks": [{"task": task, "n_steps": 5000, "runs": [run]}]}))
    return folder


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120)


def test_cells_studied_apart_share_the_pair_figure(tmp_path, one_error_line):
    plain = _study(tmp_path / "a", "assembling-kits", "transporter_only", {"1000": 30.0, "5000": 70.0})
    seq = _study(tmp_path / "b", "assembling-kits-seq-seen-colors", "two_stream", {"1000": 20.0, "5000": 40.0})
    out = tmp_path / "pairs.png"
    done = _run("--studies", str(plain), str(seq), "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert "assembling-kits / assembling-kits-seq-seen-colors" in done.stdout and out.stat().st_size > 10000
    alone = _run("--studies", str(plain), "--out", str(tmp_path / "x.png"))
    one_error_line(alone.returncode, alone.stderr, "no plain task studied beside a sequenced one")
    missing = _run("--studies", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.png"))
    one_error_line(missing.returncode, missing.stderr, "has no combined.json")
