"""Quickstart: demos -> training -> evaluation -> pictures, end to end, in one command, with an agent that learns.

On a CPU it trains the Transporter agent at an eighth of the published width on place-red-in-green: 10
demos, one place rotation (the task's bowls are round, so the expert's place yaw carries no information;
see ``Task.place_yaw_informative``), 400 steps at batch 1, then evaluates 20 test episodes in parallel
simulators: about 4 minutes on 2 cores (the choices and what each trades are in docs/quickstart.md). On a CUDA GPU
it trains at the published width instead. Defaults: ``configs/quickstart.toml``. Either way it saves the
heatmaps and a GIF of a test episode the agent solved. Everything goes to out/quickstart/; results.json
sums it up, and ``tensorboard --logdir out/quickstart`` shows the training curves and the test score. Run it
again and it resumes: finished demos and training are kept.

``--language`` runs the language lesson instead (``[language]`` in ``configs/quickstart.toml``, output in
out/quickstart-language/): the two-stream agent on put-one-block-in-bowl-seen-colors, where only the sentence
says which of three blocks to pick and which of two bowls to fill, trained on every instruction of each demo
scene with sentence features centred on the training instructions (two documented departures from the
reference; ``--no-every-instruction --no-center-sentences`` turns them off). Besides the test score it measures
instruction following (another block named on each test scene: is that block picked?) and draws one scene
under two instructions. CLIP's weights are the published ones where they can be had (Hugging Face cache or
network), otherwise seeded random weights, said on the first line and recorded in results.json;
``--clip-weights PATH`` takes an offline file.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from typing import Any

import torch

from cliport import tasks
from cliport.agents import agent_class, agent_names, load_agent
from cliport.cli.common import OneLineParser, run_cli
from cliport.data.generate import DemoConfig, generate
from cliport.errors import ConfigError, RunDirError
from cliport.evaluation.evaluate import evaluate
from cliport.evaluation.free_form import run_instruction
from cliport.evaluation.instruction_following import instruction_following, scene_instruction, two_instructions_figure
from cliport.train.config import TrainConfig
from cliport.train.recipes import recipe_names
from cliport.train.trainer import load_run_config, train
from cliport.utils.config import read_defaults
from cliport.utils.files import write_json
from cliport.utils.tensorboard import log_result, summary_writer


def parse_args(device: str) -> Any:
    early = argparse.ArgumentParser(add_help=False)
    early.add_argument("--language", action="store_true")
    language = early.parse_known_args()[0].language
    defaults = read_defaults("quickstart")
    if language:
        defaults = defaults["language"]
    per_device = defaults[device]
    parser = OneLineParser(prog="quickstart.py", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--language",
        action="store_true",
        help="the language lesson: a language-conditioned agent, instruction following, a two-instruction figure",
    )
    parser.add_argument("--task", default=defaults["task"])
    parser.add_argument("--agent", default=defaults["agent"], choices=agent_names())
    parser.add_argument(
        "--clip-weights",
        default=defaults.get("clip_weights", "auto"),
        help="CLIP's weights for agents that use CLIP: 'auto' (the published ones where they can be had, "
        "else seeded random ones, said and recorded), 'openai', 'random' or a file",
    )
    parser.add_argument(
        "--out",
        default="out/quickstart-language" if language else "out/quickstart",
        help="output folder (demos, run, pictures, results.json)",
    )
    parser.add_argument("--demos", type=int, default=defaults["demos"], help="oracle demonstrations to train on")
    parser.add_argument("--steps", type=int, default=per_device["steps"], help="training steps")
    parser.add_argument("--batch-size", type=int, default=defaults["batch_size"])
    parser.add_argument("--width", type=float, default=per_device["width"], help="network width (1.0 = published)")
    parser.add_argument(
        "--map-scale",
        type=float,
        default=per_device.get("map_scale", 1.0),
        help="the nets' map size / the top-down map's (1.0 = published; see docs/agents.md)",
    )
    parser.add_argument(
        "--lr", type=float, default=defaults.get("lr"), help="Adam learning rate (default: the agent's)"
    )
    parser.add_argument(
        "--n-rotations", type=int, help="place rotations (default: 1 where the task's place yaw says nothing, else 36)"
    )
    parser.add_argument("--episodes", type=int, default=defaults["episodes"], help="test episodes")
    parser.add_argument("--camera-scale", type=float, default=per_device["camera_scale"])
    parser.add_argument("--seed", type=int, default=0, help="training seed")
    parser.add_argument(
        "--recipe", default=defaults["recipe"], choices=recipe_names(), help="training recipe (configs/recipes.toml)"
    )
    parser.add_argument(
        "--every-instruction",
        action=argparse.BooleanOptionalAction,
        default=defaults.get("every_instruction", False),
        help="record every instruction of each demo scene with the oracle's action for it, and train on all of them",
    )
    parser.add_argument(
        "--center-sentences",
        action=argparse.BooleanOptionalAction,
        default=defaults.get("center_sentences", False),
        help="the agent reads sentence features centred on its training instructions' mean (language agents)",
    )
    parser.add_argument(
        "--swap-scenes",
        type=int,
        default=defaults.get("swap_scenes", 0),
        help="test scenes on which instruction following is measured (each gives one swap per other block)",
    )
    args = parser.parse_args()
    for name in ("demos", "steps", "batch_size", "episodes"):
        if getattr(args, name) < 1:
            raise ConfigError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    tasks.resolve(args.task)
    if args.center_sentences and not agent_class(args.agent).uses_language:
        print(f"note: {args.agent} reads no instruction, so there are no sentence features to centre", file=sys.stderr)
        args.center_sentences = False
    return args


def resolve_clip_weights(args: Any) -> str | None:
    """The CLIP weights to train with (None: the agent has no CLIP); 'auto' becomes 'openai' or 'random'."""
    if "clip_weights" not in agent_class(args.agent).weight_sources:
        return None
    if args.clip_weights != "auto":
        return args.clip_weights
    from cliport.models.encoders.clip_weights import published_weights_available

    if published_weights_available():
        return "openai"
    print(
        "CLIP weights: the published ones cannot be had here (not in the Hugging Face cache, no network), so this "
        "run uses seeded RANDOM CLIP weights (recorded in results.json); pass --clip-weights PATH for a file",
        file=sys.stderr,
    )
    return "random"


def train_config(args: Any, data_dir: str, run_dir: str, n_rotations: int, clip: str | None) -> TrainConfig:
    agent_config: dict[str, Any] = {"width": args.width, "n_rotations": n_rotations, "map_scale": args.map_scale}
    if args.lr is not None:
        agent_config["lr"] = args.lr
    if clip is not None:
        agent_config["clip_weights"] = clip
    if agent_class(args.agent).uses_language:
        agent_config["center_sentences"] = args.center_sentences
    config = TrainConfig.build(
        {
            "agent": args.agent,
            "recipe": args.recipe,
            "task": args.task,
            "n_demos": args.demos,
            "n_steps": args.steps,
            "batch_size": args.batch_size,
            "data_dir": data_dir,
            "run_dir": run_dir,
            "seed": args.seed,
            "val_episodes": 0,
            "checkpoint_steps": [args.steps],
            "num_workers": 1,
            "every_instruction": args.every_instruction,
            "agent_config": agent_config,
            "env": {"camera_scale": args.camera_scale},
        }
    )
    if os.path.exists(os.path.join(run_dir, "config.json")):
        saved = load_run_config(run_dir).to_dict()
        changed = sorted(k for k, v in config.to_dict().items() if saved.get(k) != v)
        if changed:
            raise RunDirError(
                f"{run_dir} holds a quickstart run with other settings ({', '.join(changed)}): "
                "pass another --out, or delete that folder"
            )
    return config


def main() -> None:
    device = "cuda" if torch.cuda.is_available() else "cpu"
    args = parse_args(device)
    n_rotations = args.n_rotations or (36 if tasks.place_yaw_informative(args.task) else 1)
    data_dir, run_dir = os.path.join(args.out, "data"), os.path.join(args.out, "run")
    clip = resolve_clip_weights(args)
    config = train_config(args, data_dir, run_dir, n_rotations, clip)
    timings: dict[str, float] = {}
    start = time.perf_counter()

    every = ", every instruction of each scene" if args.every_instruction else ""
    print(f"1/4 demonstrations: {args.demos} oracle episodes of {args.task}{every}")
    demo_config = DemoConfig.defaults(
        data_dir=data_dir, camera_scale=args.camera_scale, every_instruction=args.every_instruction
    )
    demos = generate(args.task, "train", args.demos, demo_config)
    timings["demos_s"] = time.perf_counter() - start

    weights = f", CLIP weights {clip}" if clip is not None else ""
    weights += ", centred sentence features" if args.center_sentences else ""
    print(
        f"2/4 training {args.agent} on {device} with the {args.recipe} recipe (width {args.width}, map scale "
        f"{args.map_scale}, {n_rotations} place rotation(s), batch {args.batch_size}{weights}) for {args.steps} steps"
    )
    last = os.path.join(run_dir, "checkpoints", "last.pt")
    mark = time.perf_counter()
    if not os.path.exists(os.path.join(run_dir, "checkpoints", f"step-{args.steps:06d}.pt")):
        train(config, resume=os.path.exists(os.path.join(run_dir, "config.json")))
    timings["training_s"] = time.perf_counter() - mark

    print(f"3/4 evaluating on {args.episodes} test episodes")
    mark = time.perf_counter()
    agent = load_agent(last, device=device)
    result = evaluate(agent, args.task, "test", args.episodes, camera_scale=args.camera_scale)
    solved = [row for row in result["episodes"] if row["total_reward"] > 0.99]
    following = None
    if args.swap_scenes > 0:
        seeds = [row["seed"] for row in result["episodes"]][: args.swap_scenes]
        following = instruction_following(agent, args.task, seeds, args.camera_scale)
        print(f"    instruction following: {following['followed']} of {following['n']} swapped instructions")
    timings["evaluation_s"] = time.perf_counter() - mark
    with contextlib.closing(summary_writer(os.path.join(run_dir, "eval", "tensorboard"))) as tensorboard:
        log_result(tensorboard, f"eval/{args.task}/test", result, args.steps)  # beside training's curves

    seed = solved[0]["seed"] if solved else result["episodes"][0]["seed"]
    print(f"4/4 heatmaps and a GIF of test episode {seed}" + ("" if solved else " (none was solved)"))
    mark = time.perf_counter()
    instruction = tasks.make(args.task).lang_template or scene_instruction(args.task, seed, args.camera_scale)
    rollout = run_instruction(
        agent, args.task, "test", seed, instruction or "solve the task", args.out, args.camera_scale
    )
    figure = None
    if following is not None:
        path = os.path.join(args.out, f"{args.task}-seed{seed}-two-instructions.png")
        figure = {
            "path": path,
            "instructions": two_instructions_figure(agent, args.task, seed, path, args.camera_scale),
        }
    timings["pictures_s"] = time.perf_counter() - mark
    timings["total_s"] = time.perf_counter() - start
    summary = {
        "task": args.task,
        "agent": args.agent,
        "device": device,
        "demos": {k: demos[k] for k in ("saved", "skipped_existing", "demos_per_minute", "mb_per_step")},
        "training": {
            "agent": args.agent,
            "recipe": args.recipe,
            "steps": args.steps,
            "width": args.width,
            "map_scale": args.map_scale,
            "lr": agent.config.lr,
            "n_rotations": n_rotations,
            "batch_size": args.batch_size,
            "seed": args.seed,
            "clip_weights": clip,
            "every_instruction": args.every_instruction,
            "center_sentences": args.center_sentences,
            "run_dir": run_dir,
        },
        "test": {k: result[k] for k in ("n_episodes", "mean_score", "ci95", "success_rate", "success_ci95")},
        "solved": len(solved),
        "gif_episode": {"seed": seed, "task_reward": rollout["task_reward"], "solved": bool(solved)},
        "heatmaps": rollout["heatmaps"],
        "video": rollout["video"],
        "seconds": {k: round(v, 1) for k, v in timings.items()},
    }
    if following is not None:
        summary["instruction_following"] = {k: following[k] for k in ("rate", "n", "followed", "swaps")}
        summary["two_instructions"] = figure
    write_json(os.path.join(args.out, "results.json"), summary)
    print(json.dumps({k: v for k, v in summary.items() if k != "instruction_following"}, indent=2))
    low, high = result["success_ci95"]
    print(
        f"\nThe agent solved {len(solved)} of {result['n_episodes']} test episodes of {args.task} "
        f"(success 95% interval {low:.0f}-{high:.0f} %; {timings['total_s'] / 60:.1f} minutes).\n"
        f"Watch episode {seed}: {rollout['video']}\nIts heatmaps: {', '.join(rollout['heatmaps'])}"
    )
    if following is not None:
        print(
            f"Instruction following: {following['followed']} of {following['n']} swapped instructions picked the "
            f"named block ({100 * following['rate']:.0f} %). One scene, two instructions: {figure['path']}"
        )
    if clip == "random":
        print("CLIP's weights were random here: the agent learned the colour words from the demonstrations alone.")


if __name__ == "__main__":
    run_cli(main)
