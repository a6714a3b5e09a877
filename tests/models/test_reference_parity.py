"""Our agents compute what the reference CLIPort code computes, given the same weights.

The reference runs in a subprocess (``tests/support/reference_oracle.py``) from the folder named by
``CLIPORT_REFERENCE_DIR`` or ``--reference-dir``; without it these tests skip. For each agent the oracle
builds the reference agent with seeded random weights rescaled so its heatmaps are not flat, and runs the
reference's own ``act()`` on a simulator observation; ours loads the same weights through
:mod:`cliport.models.reference_names` (and CLIP from the oracle's CLIP state dict, through the real
weights-file loader) and acts on the same observation. CLIP runs in fp32 on both sides here (the
reference converts it to fp16, see docs/parity.md).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from cliport.agents import make_agent
from cliport.agents.base import PickPlaceAgent
from cliport.models import reference_names

pytestmark = [pytest.mark.e2e, pytest.mark.paper_size]

AGENTS = ["transporter_only", "two_stream", "clip_only"]
LANG = "put the blue block in the green bowl"


@pytest.fixture(scope="module")
def observation() -> dict[str, np.ndarray]:
    """The first observation of put-block-in-bowl-seen-colors seed 0, full-resolution cameras."""
    from cliport import tasks
    from cliport.env.environment import EnvConfig, Environment

    with Environment(EnvConfig.defaults(), task=tasks.make("put-block-in-bowl-seen-colors", "train")) as env:
        obs = env.reset(seed=0)
    return {"color": obs["color"], "height": obs["height"]}


@pytest.fixture(scope="module")
def reference_runs(reference_oracle, reference_image, observation, tmp_path_factory) -> dict[str, dict[str, Any]]:
    """Per agent: the oracle's checkpoint, CLIP state dict and act() record on the observation."""
    folder = tmp_path_factory.mktemp("reference")
    request = folder / "request.pt"
    torch.save({"images": [reference_image(observation)], "lang": [LANG]}, request)
    runs = {}
    for agent in AGENTS:
        ref_name = reference_names.REFERENCE_AGENTS[agent][0]
        ckpt = folder / f"{agent}.ckpt"
        reference_oracle("weights", ref_name, str(ckpt), "--act", str(request), str(folder / f"{agent}.act.pt"))
        runs[agent] = {
            "ckpt": ckpt,
            "clip": Path(str(ckpt) + ".clip.pt"),
            "act": torch.load(folder / f"{agent}.act.pt", weights_only=True)[0],
        }
    return runs


def _our_agent(agent: str, run: dict[str, Any]) -> PickPlaceAgent:
    config: dict[str, Any] = {"width": 1.0, "n_rotations": 36, "crop_size": 64}
    if agent != "transporter_only":
        config["clip_weights"] = str(run["clip"])  # the real weights-file loader
    ours = make_agent(agent, config)
    reference = torch.load(run["ckpt"], map_location="cpu", weights_only=True)["state_dict"]
    ours.load_trainable_state_dict(reference_names.from_reference(agent, reference, ours.trainable_state_dict()))
    return ours


def _act_recording(agent: PickPlaceAgent, obs: dict[str, np.ndarray], lang: str | None) -> dict[str, Any]:
    """act() with the pick and place logits and the key and query outputs it computed on the way."""
    record: dict[str, Any] = {}
    pick_forward, place_forward = agent._pick_forward, agent._place_forward

    def pick(*args: Any) -> torch.Tensor:
        record["pick_logits"] = out = pick_forward(*args)
        return out

    def place(*args: Any) -> torch.Tensor:
        record["place_logits"] = out = place_forward(*args)
        return out

    hooks = [
        agent.place.key_net.register_forward_hook(lambda m, i, o: record.__setitem__("key", o)),
        agent.place.query_net.register_forward_hook(lambda m, i, o: record.__setitem__("query", o)),
    ]
    agent._pick_forward, agent._place_forward = pick, place  # type: ignore[method-assign]
    try:
        record["act"] = agent.act(obs, lang)
    finally:
        for hook in hooks:
            hook.remove()
    return record


def _assert_close_to_peak(ours: torch.Tensor, theirs: torch.Tensor, what: str) -> float:
    """|ours - theirs| <= 1e-5 of the reference's peak magnitude; returns the relative error."""
    theirs = theirs.reshape(ours.shape).to(ours.dtype)
    rel = float((ours - theirs).abs().max() / theirs.abs().max())
    assert rel <= 1e-5, f"{what}: max difference {rel:.2e} of the peak"
    return rel


@pytest.mark.parametrize("agent", AGENTS)
def test_agent_computes_what_the_reference_computes(agent: str, reference_runs, observation) -> None:
    run = reference_runs[agent]
    ref = run["act"]
    # The heatmaps are far from flat (each spans a good part of its peak, 10^4 times the tolerance below),
    # so equal argmaxes mean something.
    for name in ("pick_logits", "place_logits"):
        logits = ref[name]
        spread, peak = float(logits.max() - logits.min()), float(logits.abs().max())
        assert spread > max(0.5, 0.25 * peak), f"{name} span only {spread:.3g} (peak {peak:.3g})"

    ours = _act_recording(_our_agent(agent, run), observation, LANG if agent != "transporter_only" else None)
    errors = {
        "pick": _assert_close_to_peak(ours["pick_logits"][0], ref["pick_logits"], "pick logits"),
        "key": _assert_close_to_peak(ours["key"][0], ref["key"][0], "key map"),
        "query": _assert_close_to_peak(ours["query"], ref["query"], "query kernels"),
        "place": _assert_close_to_peak(ours["place_logits"][0], ref["place_logits"], "place logits"),
    }
    print(f"{agent} parity, max difference / peak: " + ", ".join(f"{k} {v:.1e}" for k, v in errors.items()))

    act = ours["act"]
    ref_pick, ref_place = ref["pick"].tolist(), ref["place"].tolist()
    assert act["pick_pix"] == (int(ref_pick[0]), int(ref_pick[1]))
    assert act["place_pix"] == (int(ref_place[0]), int(ref_place[1]))
    _, _, z, w = ref["pose1"][1].tolist()  # the reference's pose1 yaw is -theta of its bin
    assert act["place_bin"] == round(-2 * math.atan2(z, w) / (2 * math.pi / 36)) % 36
    for ours_pose, ref_pose in ((act["pose0"], ref["pose0"]), (act["pose1"], ref["pose1"])):
        np.testing.assert_allclose(ours_pose[0], ref_pose[0].numpy(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(ours_pose[1], ref_pose[1].numpy(), rtol=0, atol=1e-9)


def test_clip_trunk_sentence_and_tokens_equal_the_references(reference_oracle, reference_runs, tmp_path) -> None:
    from cliport.models.encoders.clip_encoder import load_clip

    run = reference_runs["two_stream"]
    texts = [LANG, "pack all the yellow and blue blocks into the brown box", "Stack the RED block, then the tiny one!"]
    rgb = torch.rand(2, 3, 96, 64, generator=torch.Generator().manual_seed(0))
    torch.save({"texts": texts, "rgb": rgb}, tmp_path / "request.pt")
    reference_oracle("clip", "cliport", str(run["ckpt"]), str(tmp_path / "request.pt"), str(tmp_path / "clip.pt"))
    ref = torch.load(tmp_path / "clip.pt", weights_only=True)

    clip = load_clip(str(run["clip"]))
    assert torch.equal(clip._tokenizer(texts), ref["tokens"])
    sentences = clip.sentence_features(texts)
    assert float((sentences - ref["sentences"]).abs().max() / ref["sentences"].abs().max()) < 1e-5
    levels = clip.image_features(rgb)[1:]  # layer1..4 (the stem levels differ in where they are read)
    for ours, theirs in zip(levels, ref["levels"][1:], strict=True):
        assert ours.shape == theirs.shape
        assert float((ours - theirs).abs().max() / theirs.abs().max()) < 1e-5
    # The features are not degenerate: the calibrated random trunk gives unit-scale maps.
    assert 0.1 < float(levels[-1].std()) < 100
