"""Training parity with the reference CLIPort: the same weights and samples give the same update.

Both sides start from one checkpoint the reference code wrote (seeded weights; its CLIP copies with
per-net batch-norm statistics), converted with ``cliport-convert``. The reference then runs its own
``attn_training_step`` and ``transport_training_step`` (in a subprocess, ``tests/support/reference_oracle.py train``)
on fixed simulator samples, augmentation off; ours runs the ``cliport`` recipe's steps on the same samples.
Every trainable tensor's change, the U-Net batch norms' and each net's CLIP batch-norm running statistics
must agree. Skipped without the reference code (CLIPORT_REFERENCE_DIR or --reference-dir).
"""

from __future__ import annotations

import copy
import gc
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cliport.agents import load_agent
from cliport.env import heightmap as hm
from cliport.models import correlation, reference_names
from cliport.train.convert import convert_checkpoint
from cliport.train.recipes import get_recipe
from cliport.utils.run_dir import RunDir

pytestmark = [pytest.mark.e2e, pytest.mark.paper_size]

TASK = "put-block-in-bowl-seen-colors"
SEEDS = (0, 1)  # one sample each: two training steps, the second from Adam's moments of the first
# Fewer rotations than the paper's 36 keep the reference's place step affordable on a CPU; the arithmetic
# compared (loss, gradients, Adam, batch norms) does not depend on the count.
N_ROTATIONS = 4
AGENTS = [("transporter", "transporter_only"), ("cliport", "two_stream"), ("clip_lingunet_transporter", "clip_only")]


@pytest.fixture(scope="module")
def samples() -> list[dict]:
    """Three oracle steps: observation, instruction, pick and place pixels and the place rotation bin."""
    from cliport import tasks
    from cliport.env.environment import EnvConfig, Environment
    from cliport.env.transforms import quat_to_yaw

    config = EnvConfig.defaults()
    config.camera_scale = 0.5
    out = []
    step = 2 * math.pi / N_ROTATIONS
    with Environment(config, task=tasks.make(TASK, "train")) as env:
        for seed in SEEDS:
            obs = env.reset(seed=seed)
            action = env.task.oracle_act(obs)
            (xyz0, q0), (xyz1, q1) = action["pose0"], action["pose1"]
            # The reference's labels: theta = -yaw, relative to the pick's; bin = round(theta / step) % R.
            theta = -np.float32(quat_to_yaw(q1)) + np.float32(quat_to_yaw(q0))
            out.append(
                {
                    "color": obs["color"],
                    "height": obs["height"],
                    "lang": env.lang_goal,
                    "p0": hm.xyz_to_pix(xyz0),
                    "p1": hm.xyz_to_pix(xyz1),
                    "p1_theta": float(theta),
                    "bin": int(np.int32(np.round(theta / step)) % N_ROTATIONS),
                }
            )
    return out


# The twin patches correlation.fft_cross_correlation with _longer_fft_correlation, which calls the original.
_fft_cross_correlation = correlation.fft_cross_correlation


def _longer_fft_correlation(key: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """The project's FFT correlation of the key zero-padded by 16 cells on two sides: FFTs 16 cells longer, the
    same valid values (the padding is never under a kernel there), rounded differently."""
    height, width = key.shape[-2:]
    kh, kw = kernels.shape[-2:]
    return _fft_cross_correlation(F.pad(key, (0, 16, 0, 16)), kernels)[..., : height - kh + 1, : width - kw + 1]


def _batch(sample: dict) -> dict:
    return {
        "color": sample["color"][None],
        "height": sample["height"][None],
        "pick_pix": torch.tensor([sample["p0"]]),
        "place_pix": torch.tensor([sample["p1"]]),
        "place_rot": torch.tensor([sample["bin"]]),
        "lang": [sample["lang"]],
    }


def _twin_steps(twin, recipe, samples: list[dict], patch: pytest.MonkeyPatch) -> dict[str, torch.Tensor]:
    """Our own float32 noise: the same steps computed another, equivalent way that rounds differently: the place
    correlation with longer FFTs, the frozen trunk on channels_last. (The reference's own padded conv2d measured
    the same whole-update noise, 7.9e-3 for two_stream and 5.9e-2 for clip_only, at 15-20 s more per test.)"""
    patch.setattr(correlation, "fft_cross_correlation", _longer_fft_correlation)
    if twin.encoder is not None:
        trunk = twin.encoder._trunk
        patch.setattr(twin.encoder, "_trunk", lambda rgb: trunk(rgb.contiguous(memory_format=torch.channels_last)))
    optimizer, _ = recipe.prepare(twin)
    for s in samples:
        twin.train_step(_batch(s), optimizer, loss=recipe.loss)
    return twin.trainable_state_dict()


def _compare(
    after: dict, before: dict, theirs: dict, trainable: set[str], noise: dict | None
) -> tuple[list[str], list[str], float, float, int]:
    """Errors past the bounds, tensors over their bound, the whole update's error and its noise floor, and how
    many CLIP running statistics moved. Without ``noise`` (the twin's state) every floor is 0."""
    errors, noisy, stats_moved = [], [], 0
    ours_all, ref_all, twin_all = [], [], []
    for key, value in after.items():
        twin = value if noise is None else noise[key]
        clip_stats = "encoder_stats" in key
        if key in trainable or (key.endswith(("running_mean", "running_var")) and not clip_stats):
            # A weight's update, or a U-Net batch norm's running statistic, which tracks each step's batch moments
            # and is compared like an update (as an absolute 1e-5 it is at the mercy of float32: measured 7e-7 off
            # the reference's for the same tensor run alone, 1.0e-5 after another agent's test in the process).
            ours_delta, ref_delta = value - before[key], theirs[key] - before[key]
            if key in trainable:
                ours_all.append(ours_delta.flatten())
                ref_all.append(ref_delta.flatten())
                twin_all.append((twin - before[key]).flatten())
            scale = float(ref_delta.norm())
            error = float((ours_delta - ref_delta).norm()) / max(scale, 1e-30)
            floor = float((twin - value).norm()) / max(scale, 1e-30)
            bound = 1e-3
        elif clip_stats and key.endswith(("running_mean", "running_var")):
            # CLIP's running statistics: the 1e-5, no allowance
            stats_moved += not torch.equal(theirs[key], before[key])
            scale = max(1.0, float(theirs[key].abs().max()))
            error = float((value - theirs[key]).abs().max()) / scale
            floor, bound = 0.0, 1e-5
        else:
            continue
        # The bound, or, where float32 makes this computation that ill-conditioned, 10x the difference between
        # two equivalent computations of ours (the reference's is one more such computation; a wrong loss, batch-norm
        # mode or optimiser moves updates by O(1)).
        if error > bound:
            noisy.append(f"{key} {error:.1e} (ours vs ours {floor:.1e})")
        if scale == 0 or error > max(bound, 10 * floor):
            errors.append(f"{key}: off the reference's by {error:.2e} (of {scale:.2e}); ours vs ours {floor:.2e}")
    ours_flat, ref_flat, twin_flat = torch.cat(ours_all), torch.cat(ref_all), torch.cat(twin_all)
    overall = float((ours_flat - ref_flat).norm() / ref_flat.norm())
    overall_floor = float((ours_flat - twin_flat).norm() / ref_flat.norm())
    return errors, noisy, overall, overall_floor, stats_moved


@pytest.mark.parametrize("reference_agent,ours", AGENTS)
def test_cliport_recipe_updates_as_the_reference_trains(
    reference_agent, ours, reference_oracle, reference_image, samples, tmp_path, monkeypatch
) -> None:
    folder = tmp_path / f"{TASK}-{reference_agent}-n100-train" / "checkpoints"
    folder.mkdir(parents=True)
    ckpt = folder / "steps=1000-val_loss=0.12345678.ckpt"
    request = tmp_path / "frames.pt"
    frames = [
        {"img": reference_image(s), "p0": torch.tensor(s["p0"]), "p1": torch.tensor(s["p1"]),
         "p1_theta": s["p1_theta"], "lang": s["lang"]}
        for s in samples
    ]  # fmt: skip
    torch.save({"frames": frames}, request)
    trained = tmp_path / "trained.pt"
    reference_oracle(
        "train", reference_agent, str(ckpt), str(request), str(trained), "--perturb-clip-bn",
        "--n-rotations", str(N_ROTATIONS),
    )  # fmt: skip
    reference = torch.load(trained, weights_only=True)
    trained.unlink()  # two_stream's is 2.3 GB; the checkpoints below another 2.5

    summary = convert_checkpoint(str(ckpt), str(tmp_path / "run"), clip_weights="checkpoint", n_rotations=N_ROTATIONS)
    for path in folder.iterdir():
        path.unlink()
    agent = load_agent(RunDir(str(tmp_path / "run")).checkpoint(summary["global_step"]))
    # The reference's key net reads its input in channels_last (a permuted (H, W, C) array); the same layout
    # here makes the float32 convolutions round alike (NCHW moves early key-layer updates by up to 3 %).
    agent.place.key_memory_format = torch.channels_last
    before = {k: v.clone() for k, v in agent.trainable_state_dict().items()}
    recipe = get_recipe("cliport")
    twin = copy.deepcopy(agent)  # trained only where a tensor is over its bound, to measure our float32 noise
    optimizer, applied = recipe.prepare(agent)
    assert applied == (0 if ours == "transporter_only" else 3)
    infos = [agent.train_step(_batch(s), optimizer, loss=recipe.loss) for s in samples]
    after = {k: v.clone() for k, v in agent.trainable_state_dict().items()}
    trainable = {name for name, p in agent.named_parameters() if p.requires_grad}
    del agent, optimizer  # one paper-size agent in training at a time: two_stream's takes ~10 GB
    gc.collect()
    theirs = reference_names.from_reference(ours, reference["state_dict"], after)
    errors, noisy, overall, overall_floor, stats_moved = _compare(after, before, theirs, trainable, noise=None)
    floor_note = "every tensor within its bound"
    if errors or overall > 1e-3:  # over a bound somewhere: measure our own float32 noise there
        with monkeypatch.context() as patch:
            noise = _twin_steps(twin, recipe, samples, patch)
        errors, noisy, overall, overall_floor, stats_moved = _compare(after, before, theirs, trainable, noise)
        floor_note = f"ours vs ours {overall_floor:.2e}; {len(noisy)} tensors over their bound: {noisy}"
    del twin
    print(f"{ours}: whole update within {overall:.2e} of the reference's ({floor_note})")
    assert not errors, "\n".join(errors[:20])
    assert overall <= max(1e-3, 3 * overall_floor)
    if ours != "transporter_only":
        assert stats_moved > 0  # CLIP's running statistics drifted in the reference's steps, and ours agree

    # The reference's losses are the per-sample cross-entropies divided by the map's cells. The seeded weights'
    # logits span ~1e4, so a cross-entropy carries the forward's float32 rounding (~6e-6 of the peak).
    h, w = samples[0]["height"].shape
    for info, (pick, place) in zip(infos, reference["losses"], strict=True):
        assert info["pick_loss"] == pytest.approx(pick * h * w, rel=5e-3)
        assert info["place_loss"] == pytest.approx(place * N_ROTATIONS * h * w, rel=5e-3)
