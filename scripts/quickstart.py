"""Quickstart: build the workcell, run one pick-and-place, and save what the agent sees.

Writes out/quickstart/{before,after}.png (fused top-down colour and height, and the front camera)
and prints a JSON summary. Later issues extend this to demos -> training -> evaluation.
"""

from __future__ import annotations

import argparse
import json
import math
import os

import cv2
import numpy as np
import pybullet as p

from cliport.env import shapes
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import quat_to_yaw, yaw_to_quat


def _panel(obs: dict) -> np.ndarray:
    color = obs["color"]
    height = np.clip(obs["height"] / 0.1 * 255, 0, 255).astype(np.uint8)
    height = cv2.applyColorMap(height, cv2.COLORMAP_VIRIDIS)[..., ::-1]
    camera = obs["cameras"][0]["color"]
    camera = cv2.resize(camera, (int(camera.shape[1] * 320 / camera.shape[0]), 320))
    return np.concatenate([color, height, camera], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/quickstart")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    with Environment(EnvConfig.defaults()) as env:
        env.reset(args.seed)
        colors = [(255, 87, 89), (78, 121, 167), (89, 169, 79)]
        blocks = []
        for color in colors:
            xy = rng.uniform([0.35, -0.35], [0.65, 0.35])
            pose = ((float(xy[0]), float(xy[1]), 0.02), yaw_to_quat(float(rng.uniform(0, math.pi))))
            blocks.append(env.add_object(shapes.box(env.client, (0.04, 0.04, 0.04), pose, color=color)))
        env.settle()
        before = env.observe(raw_images=True)
        red_pos, red_quat = p.getBasePositionAndOrientation(blocks[0], physicsClientId=env.client)
        goal = (0.5, 0.0)
        action = {
            "pose0": (red_pos[:2] + (0.04,), red_quat),
            "pose1": ((*goal, 0.04), yaw_to_quat(quat_to_yaw(red_quat) + math.pi / 4)),
        }
        _, _, _, info = env.step(action)
        after = env.observe(raw_images=True)
        end, _ = p.getBasePositionAndOrientation(blocks[0], physicsClientId=env.client)
        cv2.imwrite(os.path.join(args.out, "before.png"), _panel(before)[..., ::-1])
        cv2.imwrite(os.path.join(args.out, "after.png"), _panel(after)[..., ::-1])
        summary = {
            "renderer": env.renderer_name,
            "grasped": info["grasped"],
            "placement_error_m": round(float(np.linalg.norm(np.subtract(end[:2], goal))), 4),
            "images": [os.path.join(args.out, "before.png"), os.path.join(args.out, "after.png")],
        }
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
