"""Shared pytest set-up. Three tiers: the default run (the README's test command); ``e2e`` tests (end to end
and paper-size: skipped unless ``--e2e``; CI runs them after the default run, ``pytest --e2e -m e2e ...``);
``slow`` tests (run only with ``--runslow``). GPU tests skip where CUDA is absent. Tests that build paper-size
nets are also marked ``paper_size``: CI runs them serially (``pytest --e2e -m paper_size``, no ``-n``), so that
two of them are never in memory, or on disk, at once. Tests that start processes on every core (a Ray cluster) are
also marked ``whole_machine``: CI runs them alone, after the other end-to-end tests."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np
import pytest

from cliport.data.episode_io import save_episode
from cliport.env.transforms import yaw_to_quat


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--runslow", action="store_true", default=False, help="also run tests marked slow")
    parser.addoption(
        "--e2e", action="store_true", default=False, help="also run the end-to-end and paper-size tests (marked e2e)"
    )
    parser.addoption(
        "--reference-dir",
        default=None,
        help="folder of the reference CLIPort code for the parity tests (default: $CLIPORT_REFERENCE_DIR)",
    )


def pytest_configure(config: pytest.Config) -> None:
    """Under xdist, each worker (and the subprocesses its tests start) gets its share of the cores: n workers
    with every core's threads each oversubscribe the CPU n-fold, and OpenMP threads spinning while they wait
    make that far worse (measured: a two-thread training step 20x slower beside another two-thread process)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        threads = str(max(1, (os.cpu_count() or 1) // workers))
        os.environ["OMP_NUM_THREADS"] = os.environ["MKL_NUM_THREADS"] = threads
        import torch

        torch.set_num_threads(int(threads))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    skip_slow = pytest.mark.skip(reason="slow: pass --runslow to run")
    skip_e2e = pytest.mark.skip(reason="end to end: pass --e2e to run (CI runs them as its second command)")
    cuda = None
    for item in items:
        if "slow" in item.keywords and not config.getoption("--runslow"):
            item.add_marker(skip_slow)
        if "e2e" in item.keywords and not config.getoption("--e2e"):
            item.add_marker(skip_e2e)
        if "gpu" in item.keywords:
            if cuda is None:
                import torch

                cuda = torch.cuda.is_available()
            if not cuda:
                item.add_marker(pytest.mark.skip(reason="gpu: no CUDA device"))


# The paper-size tier's temporary folders peak at 7.6 GB (4.0 GB of files shared by its tests, 3.6 GB more in one
# test's checkpoints; measured 2026-11-28): a disk with less room is named before a test, not by torch.save mid-write.
PAPER_SIZE_DISK_GB = 8.0


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A paper-size test fails at once, in one line and before its fixtures write anything, where the disk of the
    temporary folders has too little room."""
    if "paper_size" not in item.keywords:
        return
    root = str(item.config.option.basetemp or tempfile.gettempdir())
    while not os.path.exists(root):
        root = os.path.dirname(root)
    free_gb = shutil.disk_usage(root).free / 2**30
    if free_gb < PAPER_SIZE_DISK_GB:
        pytest.fail(
            f"paper-size test: {free_gb:.1f} GB free on the disk of {root}, the tier needs {PAPER_SIZE_DISK_GB:.0f} GB "
            "(full-size checkpoints); free some space",
            pytrace=False,
        )


@pytest.fixture(scope="session")
def reference_dir(pytestconfig: pytest.Config) -> str:
    """The reference CLIPort folder (``--reference-dir`` or ``$CLIPORT_REFERENCE_DIR``); skips without one."""
    folder = pytestconfig.getoption("--reference-dir") or os.environ.get("CLIPORT_REFERENCE_DIR")
    if not folder:
        pytest.skip("parity test: no reference CLIPort code (set CLIPORT_REFERENCE_DIR or --reference-dir)")
    if not os.path.isfile(os.path.join(folder, "build_reference.py")):
        pytest.skip(f"parity test: {folder} does not hold the reference CLIPort code (no build_reference.py)")
    return os.path.abspath(folder)


@pytest.fixture(scope="session")
def reference_oracle(reference_dir: str):
    """A function running ``tests/support/reference_oracle.py --reference-dir R ARGS...`` in a subprocess."""

    def run(*args: str) -> None:
        script = os.path.join(os.path.dirname(__file__), "support", "reference_oracle.py")
        done = subprocess.run(
            [sys.executable, script, "--reference-dir", reference_dir, *args], capture_output=True, text=True
        )
        if done.returncode:
            raise AssertionError(f"reference oracle {' '.join(args[:2])} failed:\n{done.stderr[-4000:]}")

    return run


@pytest.fixture(scope="session")
def reference_utils(reference_dir: str):
    """A function running one job of ``tests/support/run_reference_utils.py`` (the reference's ``utils.py``) in a
    subprocess: ``(folder, job, **arrays) -> output arrays``."""
    runner = os.path.join(os.path.dirname(__file__), "support", "run_reference_utils.py")

    def call(folder, job: str, **arrays: np.ndarray) -> dict[str, np.ndarray]:
        src, dst = os.path.join(folder, f"{job}-in.npz"), os.path.join(folder, f"{job}-out.npz")
        np.savez(src, job=np.array(job), **arrays)
        proc = subprocess.run(
            [sys.executable, runner, reference_dir, src, dst], capture_output=True, text=True, timeout=300, cwd=folder
        )
        assert proc.returncode == 0, proc.stderr[-4000:]
        with np.load(dst) as z:
            return {k: z[k] for k in z.files}

    return call


#: The semantic encoder of the tiny agents' CLIP stream (tiny_config).
TINY_CLIP = "cliport-RN-tiny"


@pytest.fixture(scope="session")
def tiny_config():
    """``tiny_config(agent, **overrides)``: settings of a tiny agent (an eighth of the published width, 32-pixel
    crops, 8 rotations, random pretrained weights; where the agent has a CLIP semantic stream, the tiny CLIP
    ``cliport-RN-tiny``: a frozen RN50 costs most of a tiny agent's step) for fast CPU tests. Tests of CLIPort's
    own nets (shapes, parity, weights files) name ``semantic_encoder="RN50-quickgelu"``."""
    from dataclasses import fields

    from cliport.agents import agent_class

    def config(agent: str, **overrides: object) -> dict[str, object]:
        cls = agent_class(agent)
        base: dict[str, object] = {"width": 0.125, "crop_size": 32, "n_rotations": 8}
        if "semantic_encoder" in {f.name for f in fields(cls.config_class)}:
            base["semantic_encoder"] = TINY_CLIP
        return {**base, **dict.fromkeys(cls.weight_sources, "random"), **overrides}

    return config


def assert_one_error_line(code: object, stderr: str, *phrases: str, status: int | None = None) -> str:
    """Check a command's failure: exit ``code`` non-zero (``status``: exactly that), ``stderr`` exactly one
    line starting with ``error: `` (no traceback) and containing every one of ``phrases``; returns that line."""
    lines = stderr.strip().splitlines()
    assert (code not in (0, None)) if status is None else (code == status), (code, stderr)
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    assert "Traceback" not in stderr, stderr
    for phrase in phrases:
        assert phrase in lines[0], (phrase, lines[0])
    return lines[0]


@pytest.fixture(scope="session")
def one_error_line():
    """:func:`assert_one_error_line`: ``(code, stderr, *phrases, status=None)`` -> the one ``error:`` line."""
    return assert_one_error_line


def _reference_image(obs: dict[str, np.ndarray]):
    """The reference agents' input for an observation: colour 0..255 and the height repeated 3x, (H, W, 6)
    float32 (a torch tensor, for the oracle's request files)."""
    import torch

    height = obs["height"][..., None].repeat(3, axis=-1)
    return torch.from_numpy(np.concatenate([obs["color"].astype(np.float32), height], axis=-1))


@pytest.fixture(scope="session")
def reference_image():
    """:func:`_reference_image`: observation -> the reference agents' (H, W, 6) input."""
    return _reference_image


def _synthetic_dataset(root: str, n_episodes: int = 3) -> str:
    """Episodes whose images carry unique markers at the pick and place pixels."""
    folder = os.path.join(root, "place-red-in-green-train")
    os.makedirs(folder)
    rng = np.random.default_rng(0)
    for e in range(n_episodes):
        steps = []
        for _ in range(2):
            color = rng.integers(0, 50, size=(320, 160, 3), dtype=np.uint8)
            height = np.zeros((320, 160), np.float32)
            pick, place = (
                (int(rng.integers(40, 280)), int(rng.integers(20, 140))),
                (
                    int(rng.integers(40, 280)),
                    int(rng.integers(20, 140)),
                ),
            )
            # 3x3 markers: a nearest-neighbour rotation moves a scene point by up to ~0.7 px.
            color[pick[0] - 1 : pick[0] + 2, pick[1] - 1 : pick[1] + 2] = (255, 0, 0)
            color[place[0] - 1 : place[0] + 2, place[1] - 1 : place[1] + 2] = (0, 255, 0)
            height[pick[0] - 1 : pick[0] + 2, pick[1] - 1 : pick[1] + 2] = 0.05
            pose0 = ((0.25 + pick[1] * 0.003125, -0.5 + pick[0] * 0.003125, 0.05), yaw_to_quat(0.3))
            pose1 = ((0.25 + place[1] * 0.003125, -0.5 + place[0] * 0.003125, 0.05), yaw_to_quat(0.3 + math.pi / 2))
            steps.append(
                {
                    "obs": {"color": color, "height": height},
                    "action": {"pose0": pose0, "pose1": pose1},
                    "reward": 0.5,
                    "lang_goal": f"episode {e}",
                }
            )
        save_episode(os.path.join(folder, f"{2 * e:06d}.npz"), steps, {"task": "place-red-in-green", "seed": 2 * e})
    return folder


@pytest.fixture(scope="session")
def make_synthetic_dataset():
    """A function (root, n_episodes) writing place-red-in-green episodes with markers at the action pixels."""
    return _synthetic_dataset


def _variant_dataset(root: str) -> str:
    """One put-one-block-in-bowl-seen-colors episode of a blank scene whose step records two variants: pick
    (x, 0) and place (x, 0.2) with x 0.3 for "gray", 0.4 "blue", 0.5 "green" ("put the X block in the red
    bowl"); returns its folder."""
    from cliport.data.episode_io import dataset_dir, episode_path, save_episode

    folder = dataset_dir(root, "put-one-block-in-bowl-seen-colors", "train")
    os.makedirs(folder)
    obs = {"color": np.zeros((320, 160, 3), np.uint8), "height": np.zeros((320, 160), np.float32)}

    def action(x: float) -> dict:
        return {"pose0": ((x, 0.0, 0.02), (0, 0, 0, 1)), "pose1": ((x, 0.2, 0.02), (0, 0, 0, 1))}

    variants = [
        ("put the blue block in the red bowl", action(0.4)),
        ("put the green block in the red bowl", action(0.5)),
    ]
    step = {"obs": obs, "action": action(0.3), "reward": 1.0, "lang_goal": "put the gray block in the red bowl"}
    save_episode(episode_path(folder, 0), [{**step, "variants": variants}], {"task": "x", "seed": 0})
    return folder


@pytest.fixture(scope="session")
def make_variant_dataset():
    """A function (root) writing :func:`_variant_dataset`'s episode."""
    return _variant_dataset


def _two_bowl_dataset(root: str) -> None:
    """One put-one-block-in-bowl-seen-colors step under four instructions: the gray block (at x 0.3) or the blue
    one (x 0.45) into the red bowl at (0.3, 0.2) or the blue bowl at (0.6, -0.2). The oracle picks a random point
    of a block, so the gray block's two picks are 2.2 cm apart."""
    from cliport.data.episode_io import dataset_dir, episode_path, save_episode

    folder = dataset_dir(root, "put-one-block-in-bowl-seen-colors", "train")
    os.makedirs(folder)
    rng = np.random.default_rng(0)
    obs = {"color": rng.integers(0, 255, (320, 160, 3), np.uint8), "height": np.zeros((320, 160), np.float32)}

    def action(pick: tuple[float, float], place: tuple[float, float]) -> dict:
        return {"pose0": ((*pick, 0.02), (0, 0, 0, 1)), "pose1": ((*place, 0.02), (0, 0, 0, 1))}

    variants = [
        ("put the gray block in the blue bowl", action((0.32, 0.01), (0.6, -0.2))),
        ("put the blue block in the red bowl", action((0.45, 0.0), (0.3, 0.2))),
        ("put the blue block in the blue bowl", action((0.45, 0.0), (0.6, -0.2))),
    ]
    step = {"obs": obs, "action": action((0.3, 0.0), (0.3, 0.2)), "reward": 1.0}
    step["lang_goal"] = "put the gray block in the red bowl"
    save_episode(episode_path(folder, 0), [{**step, "variants": variants}], {"task": "x", "seed": 0})


@pytest.fixture(scope="session")
def make_two_bowl_dataset():
    """A function (root) writing :func:`_two_bowl_dataset`'s episode."""
    return _two_bowl_dataset


#: Kinds of broken weight files every weights loader must turn into one line, and a phrase of that line.
BAD_WEIGHT_FILES = {
    "random-bytes": "not a PyTorch state-dict file",
    "truncated": "truncated or corrupt",
    "empty": "empty or truncated",
    "fake-safetensors": "not a valid safetensors file",
    "pickled-module": "pickled Python objects",
    "not-a-dict": "holds a list",
}


def write_bad_weight_file(folder, kind: str, stem: str):
    """Write a broken weights file of one of the :data:`BAD_WEIGHT_FILES` kinds into ``folder``; returns
    its path and the phrase its error line must contain."""
    import pathlib

    import torch

    folder = pathlib.Path(folder)
    suffix = {"fake-safetensors": ".safetensors", "empty": ".pth"}.get(kind, ".pt")
    path = folder / f"{stem}{suffix}"
    if kind in ("random-bytes", "fake-safetensors"):
        path.write_bytes(os.urandom(4096))
    elif kind == "truncated":
        torch.save({"w": torch.zeros(1000)}, path)
        path.write_bytes(path.read_bytes()[:2000])
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "pickled-module":
        torch.save(torch.nn.Linear(2, 2), path)
    else:
        assert kind == "not-a-dict", kind
        torch.save([torch.zeros(2)], path)
    return path, BAD_WEIGHT_FILES[kind]


@pytest.fixture
def bad_weight_file(tmp_path):
    """``bad_weight_file(kind, stem)`` -> (path, phrase) for a kind of :data:`BAD_WEIGHT_FILES` (see
    :func:`write_bad_weight_file`), None for any other kind (a model-specific one the test writes itself)."""
    return lambda kind, stem: write_bad_weight_file(tmp_path, kind, stem) if kind in BAD_WEIGHT_FILES else None


class RunsCode:
    """Pickles as a call of ``os.system(command)``: what a malicious checkpoint does when unpickled."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self):
        return (os.system, (self.command,))


@pytest.fixture
def runs_code():
    """``runs_code(command)``: an object whose unpickling would run the shell ``command`` (:class:`RunsCode`)."""
    return RunsCode
