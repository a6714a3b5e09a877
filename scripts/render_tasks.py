"""Write a picture of every task's first scene to docs/tasks/: the fused top-down colour the agents see
beside the front camera's view, titled with the task name and its first instruction.

Usage: python scripts/render_tasks.py [--tasks T ...] [--out docs/tasks] [--seed 0]
"""

from __future__ import annotations

import argparse
import os

import cv2
import numpy as np

from cliport import tasks
from cliport.env.environment import EnvConfig, Environment


def render(task_name: str, seed: int) -> tuple[np.ndarray, str]:
    task = tasks.make(task_name, "train")
    with Environment(EnvConfig.defaults(), task=task) as env:
        obs = env.reset(seed)
        camera = env.observe(raw_images=True)["cameras"][0]["color"]
        instruction = env.lang_goal or ""
    top = obs["color"]
    camera = cv2.resize(camera, (427, 320), interpolation=cv2.INTER_AREA)
    image = np.concatenate([top, np.full((320, 6, 3), 255, np.uint8), camera], axis=1)
    banner = np.full((40, image.shape[1], 3), 255, np.uint8)
    cv2.putText(banner, task_name, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(banner, instruction[:75], (6, 34), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (60, 60, 60), 1, cv2.LINE_AA)
    return np.concatenate([banner, image], axis=0), instruction


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=None)
    parser.add_argument("--out", default="docs/tasks")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    for name in args.tasks or tasks.names():
        image, instruction = render(name, args.seed)
        path = os.path.join(args.out, f"{name}.jpg")
        cv2.imwrite(path, image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
        print(f"{path}: {instruction}")


if __name__ == "__main__":
    main()
