"""A simulator scene written to disk as camera files, and a tiny untrained run folder to predict with."""

from __future__ import annotations

import dataclasses
import json
import os

import cv2
import numpy as np
import pytest

from cliport.utils.files import write_json
from cliport.utils.run_dir import RunDir

TASK = "block-insertion"


def make_run(
    root: str, agent_config: dict, agent_name: str = "transporter_only", sharpen_on: dict | None = None
) -> str:
    """A run folder holding config.json, checkpoints/step-000001.pt, last.pt and val.json (best = 1).

    ``sharpen_on``: an observation (``color``, ``height``) the agent is first trained on until both
    cross-entropies are below 0.5, towards picking the first (raster order) cell of its top surface and
    placing it back there, so that its heatmaps have clear maxima that a small change of the input does not
    move (an untrained agent's are nearly flat). A corner of the surface, not its argmax: the top is a
    plateau of equal cells that a convolution cannot tell apart, and 40 steps towards one of them left a
    3 % peak that 0.1 mm depth steps moved 170 pixels (CI failed on it).
    """
    import numpy as np
    import torch

    from cliport.agents import make_agent
    from cliport.agents.loss import optimizer_step
    from cliport.train.config import TrainConfig

    config = TrainConfig.build(
        {"agent": agent_name, "task": TASK, "agent_config": agent_config, "env": {"camera_scale": 0.5}}
    )
    run = RunDir(root)
    os.makedirs(root, exist_ok=True)
    write_json(run.config, config.to_dict())
    torch.manual_seed(0)
    agent = make_agent(agent_name, config.agent_config)
    if sharpen_on is not None:
        height = sharpen_on["height"]
        pick = tuple(int(v) for v in np.argwhere(height >= height.max() - 0.002)[0])
        batch = {
            "color": torch.from_numpy(sharpen_on["color"])[None],
            "height": torch.from_numpy(height)[None],
            "pick_pix": torch.tensor([pick]),
            "place_pix": torch.tensor([pick]),
            "place_rot": torch.tensor([0]),
            "lang": ["insert the block"],
        }
        optimizer = torch.optim.Adam(agent.trainable_parameters(), lr=1e-3)
        agent.train()
        for _ in range(200):
            info = optimizer_step(agent.compute_loss, batch, optimizer)
            if info["pick_loss"] < 0.5 and info["place_loss"] < 0.5:
                break
        else:
            raise AssertionError(f"the fixture agent did not learn its one sample in 200 steps: {info}")
    agent.save_checkpoint(run.checkpoint(1))
    agent.save_checkpoint(run.checkpoint("last"))
    write_json(run.val, {"best_step": 1, "checkpoints": {"1": {"mean_score": 0.0}}})
    return root


def write_scene(obs: dict, cameras: list, folder: str, png_scale: float | None = None) -> dict[str, list[str] | str]:
    """Write the raw camera images of an observation: c{i}.png, depth d{i}.npy (float metres) or, with
    ``png_scale``, d{i}.png (uint16 = depth / png_scale; beyond the 16-bit range = 0, no reading), and
    cameras.json from the CameraConfigs (``dataclasses.asdict``, plus depth_scale for PNG depth)."""
    os.makedirs(folder, exist_ok=True)
    rgb, depth, cams = [], [], []
    for i, (img, cam) in enumerate(zip(obs["cameras"], cameras, strict=True)):
        rgb.append(os.path.join(folder, f"c{i}.png"))
        cv2.imwrite(rgb[-1], img["color"][..., ::-1])
        d = img["depth"]
        if png_scale is None:
            depth.append(os.path.join(folder, f"d{i}.npy"))
            np.save(depth[-1], d)
        else:
            units = np.round(d / png_scale)
            units[units > 65535] = 0
            depth.append(os.path.join(folder, f"d{i}.png"))
            cv2.imwrite(depth[-1], units.astype(np.uint16))
            cam = dataclasses.replace(cam, depth_scale=png_scale)
        cams.append(dataclasses.asdict(cam))
    path = os.path.join(folder, "cameras.json")
    with open(path, "w") as f:
        json.dump(cams, f)
    return {"rgb": rgb, "depth": depth, "cameras": path}


@pytest.fixture(scope="session")
def sim_scene():
    """(observation with raw images, camera configs, instruction) of block-insertion seed 0 at camera scale 0.5."""
    from cliport import tasks
    from cliport.env.environment import EnvConfig, Environment

    with Environment(EnvConfig.defaults(camera_scale=0.5, raw_images=True), task=tasks.make(TASK, "train")) as env:
        obs = env.reset(0)
        return obs, list(env.camera_configs), env.lang_goal or "insert the block"


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory, sim_scene, tiny_config):
    config = tiny_config("transporter_only", n_rotations=4)
    return make_run(str(tmp_path_factory.mktemp("run")), config, sharpen_on=sim_scene[0])


@pytest.fixture(scope="session")
def untrained_run(tmp_path_factory, tiny_config):
    """The run ``tiny_run`` is, before its training: for what is decided before the agent predicts."""
    return make_run(str(tmp_path_factory.mktemp("untrained-run")), tiny_config("transporter_only", n_rotations=4))


@pytest.fixture
def scene_files():
    """:func:`write_scene`: (obs, cameras, folder, png_scale=None) -> {"rgb", "depth", "cameras"} paths."""
    return write_scene
