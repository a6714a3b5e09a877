"""A checkpoint written the way the reference CLIPort code writes them converts, and the converted run acts
exactly as the reference agent whose state the file holds, on simulator observations.

The reference runs in a subprocess (``tests/support/reference_oracle.py``; CLIPORT_REFERENCE_DIR or
--reference-dir, skipped without it). Its three CLIP copies get different batch-norm statistics, as its
training leaves them, so the converted run must act with each net's own.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from cliport.agents import PickPlaceAgent
from cliport.train.convert import convert_checkpoint
from cliport.utils.run_dir import RunDir

pytestmark = [pytest.mark.e2e, pytest.mark.paper_size]

TASK = "put-block-in-bowl-seen-colors"
SEEDS = (0, 2)


@pytest.fixture(scope="module")
def observations() -> list[tuple[dict[str, np.ndarray], str]]:
    from cliport import tasks
    from cliport.env.environment import EnvConfig, Environment

    out = []
    with Environment(EnvConfig.defaults(), task=tasks.make(TASK, "train")) as env:
        for seed in SEEDS:
            obs = env.reset(seed=seed)
            out.append(({"color": obs["color"], "height": obs["height"]}, env.lang_goal))
    return out


@pytest.mark.parametrize("reference_agent", ["transporter", "cliport"])
def test_converted_checkpoint_acts_as_the_reference_agent(
    reference_agent, reference_oracle, reference_image, observations, tmp_path
) -> None:
    folder = tmp_path / f"{TASK}-{reference_agent}-n100-train" / "checkpoints"
    folder.mkdir(parents=True)
    ckpt = folder / "steps=1000-val_loss=0.12345678.ckpt"
    request = tmp_path / "request.pt"
    torch.save({"images": [reference_image(o) for o, _ in observations], "lang": [lang for _, lang in observations]},
               request)  # fmt: skip
    # One reference process writes the checkpoint and acts with the agent that holds its state.
    reference_oracle("weights", reference_agent, str(ckpt), "--perturb-clip-bn", "--act", str(request),
                     str(tmp_path / "act.pt"))  # fmt: skip
    expected = torch.load(tmp_path / "act.pt", weights_only=True)

    run = tmp_path / "run"
    summary = convert_checkpoint(str(ckpt), str(run), clip_weights="checkpoint")
    assert summary["reference_agent"] == reference_agent and summary["task"] == TASK
    agent = PickPlaceAgent.from_pretrained(RunDir(str(run)).checkpoint(summary["global_step"]))
    if reference_agent == "cliport":
        # The three nets act with three different sets of CLIP statistics, as the reference's copies do.
        stats = [net.encoder_stats.as_dict() for net in (agent.pick.net, agent.place.key_net, agent.place.query_net)]
        name = "layer1.0.bn1.running_var"
        assert not torch.equal(stats[0][name], stats[1][name]) and not torch.equal(stats[1][name], stats[2][name])
        assert json.loads((run / "config.json").read_text())["agent_config"]["per_net_clip_stats"] is True
    for (obs, lang), ref in zip(observations, expected, strict=True):
        act = agent.act(obs, lang if agent.uses_language else None)
        assert act["pick_pix"] == tuple(int(x) for x in ref["pick"][:2].tolist())
        assert act["place_pix"] == tuple(int(x) for x in ref["place"][:2].tolist())
        for ours, theirs in ((act["pose0"], ref["pose0"]), (act["pose1"], ref["pose1"])):
            np.testing.assert_allclose(ours[0], theirs[0].numpy(), rtol=0, atol=1e-9)
            np.testing.assert_allclose(ours[1], theirs[1].numpy(), rtol=0, atol=1e-9)
        # The whole heatmaps, not only their maxima (the place map is the max over rotations).
        pick = torch.softmax(ref["pick_logits"].flatten().double(), 0).reshape(ref["pick_logits"].shape)
        place = torch.softmax(ref["place_logits"].flatten().double(), 0).reshape(ref["place_logits"].shape).amax(0)
        for ours, theirs in ((act["pick_heatmap"], pick), (act["place_heatmap"], place)):
            assert float(np.abs(ours - theirs.numpy()).max()) <= 1e-3 * float(theirs.max())
