"""Benchmark the workcell: milliseconds per observation (3 cameras + fusion) and per pick-and-place.

Prints one JSON object. Usage: python scripts/bench_env.py [--repeats 10] [--renderer auto|cpu|egl]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

from cliport.env import shapes
from cliport.env.environment import EnvConfig, Environment
from cliport.env.primitives import pick_place
from cliport.utils.machine import measurement_environment


def _scene(env: Environment) -> list[int]:
    env.reset(0)
    blocks = []
    for i, xy in enumerate([(0.4, 0.2), (0.5, -0.1), (0.6, 0.3), (0.45, -0.35)]):
        pose = ((xy[0], xy[1], 0.02), (0, 0, 0, 1))
        blocks.append(env.add_object(shapes.box(env.client, (0.04, 0.04, 0.04), pose, color=(50 * i, 120, 200))))
    env.settle()
    return blocks


def bench_observation(scale: float, renderer: str, repeats: int) -> dict:
    with Environment(EnvConfig.defaults(camera_scale=scale, renderer=renderer)) as env:
        _scene(env)
        env.observe()
        obs_ms, render_ms = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            env.render_cameras()
            render_ms.append((time.perf_counter() - t) * 1e3)
            t = time.perf_counter()
            env.observe()
            obs_ms.append((time.perf_counter() - t) * 1e3)
        return {
            "renderer": env.renderer_name,
            "image_size": list(env.camera_configs[0].image_size),
            "median_ms_per_observation": round(statistics.median(obs_ms), 1),
            "median_ms_render_3_cameras": round(statistics.median(render_ms), 1),
        }


def bench_pick_place(renderer: str, repeats: int) -> dict:
    with Environment(EnvConfig.defaults(camera_scale=0.5, renderer=renderer)) as env:
        ms, sim_steps = [], []
        for i in range(repeats):
            _scene(env)
            src, dst = ((0.4, 0.2), (0.6, -0.2)) if i % 2 == 0 else ((0.5, -0.1), (0.35, 0.25))
            action = {"pose0": ((*src, 0.04), (0, 0, 0, 1)), "pose1": ((*dst, 0.04), (0, 0, 0.38, 0.925))}
            env.robot.steps_taken = 0
            t = time.perf_counter()
            pick_place(env.robot, env.ee, action["pose0"], action["pose1"])
            ms.append((time.perf_counter() - t) * 1e3)
            sim_steps.append(env.robot.steps_taken)
        return {
            "median_ms_per_pick_place": round(statistics.median(ms), 1),
            "median_sim_steps": statistics.median(sim_steps),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--renderer", default="auto", choices=["auto", "cpu", "egl"])
    args = parser.parse_args()
    result = {
        "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version()},
        "full_resolution": bench_observation(1.0, args.renderer, args.repeats),
        "half_resolution": bench_observation(0.5, args.renderer, args.repeats),
        "pick_place": bench_pick_place(args.renderer, max(args.repeats // 2, 3)),
    }
    result["environment"] = measurement_environment()
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
