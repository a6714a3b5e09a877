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
import math
import os
import sys
import time
from typing import Any

import torch

from cliport import tasks
from cliport.agents import PickPlaceAgent, agent_class, agent_names
from cliport.agents.registry import config_classes
from cliport.cli.common import OneLineParser, run_cli
from cliport.data.generate import DemoConfig, generate
from cliport.env.config import EnvConfig
from cliport.errors import ConfigError, RunDirError
from cliport.evaluation.evaluate import evaluate
from cliport.evaluation.free_form import run_instruction
from cliport.evaluation.held_out import HeldOutCheck, record_scenes
from cliport.evaluation.instruction_following import (
    instruction_following,
    lesson_task,
    scene_instruction,
    two_instructions_figure,
)
from cliport.pretrain.transfer import colour_report
from cliport.train.config import TrainConfig, load_run_config
from cliport.train.recipes import recipe_names
from cliport.train.run_defaults import run_defaults
from cliport.train.step_timing import step_seconds
from cliport.train.trainer import train
from cliport.utils.config import add_flags, device_defaults, given_flags, merge
from cliport.utils.files import read_json, write_json
from cliport.utils.machine import measurement_environment
from cliport.utils.run_dir import RunDir
from cliport.utils.tensorboard import log_result, summary_writer

#: Train config fields (and the workcell's camera_scale) with flags of the quickstart's: the flags come from the
#: fields (cliport.utils.config.add_flags), their defaults from configs/quickstart.toml.
RUN_FLAGS = ("task", "agent", "batch_size", "seed", "recipe", "lr_cooldown", "every_instruction", "pair_contrasts")
#: Agent config fields whose flags take the quickstart's defaults (configs/quickstart.toml); the other agent fields'
#: flags take the defaults of configs/<agent>.toml.
LESSON_AGENT_FLAGS = (
    "width", "map_scale", "lr", "n_rotations", "clip_weights", "semantic_encoder", "center_sentences", "scale_up_mid"
)  # fmt: skip
#: The defaults of those flags where configs/quickstart.toml sets none (absent: None, the agent's).
FLAG_FALLBACKS: dict[str, Any] = {
    "seed": 0, "lr_cooldown": 0.0, "every_instruction": False, "map_scale": 1.0, "clip_weights": "auto",
    "center_sentences": False, "scale_up_mid": False,
}  # fmt: skip
#: Flags whose default None is decided once the others are parsed: --pair-contrasts follows --every-instruction,
#: --n-rotations is run_defaults'.
DECIDED_LATER = ("pair_contrasts", "n_rotations")


def build_parser(setting: dict[str, Any], language: bool) -> tuple[argparse.ArgumentParser, list[str]]:
    """The quickstart's parser with the defaults of ``setting`` (configs/quickstart.toml's section for the device),
    and the dests of the other agent settings' flags."""
    parser = OneLineParser(prog="quickstart.py", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--language",
        action="store_true",
        help="the language lesson: a language-conditioned agent, instruction following, a two-instruction figure",
    )
    parser.add_argument(
        "--test-task",
        action="append",
        default=[],
        help="also test on this put-one-block-in-bowl-* task (e.g. put-one-block-in-bowl-unseen-colors), split by "
        "whether the colours named are unseen; repeatable",
    )
    parser.add_argument(
        "--out",
        default="out/quickstart-language" if language else "out/quickstart",
        help="output folder (demos, run, pictures, results.json)",
    )
    parser.add_argument("--demos", type=int, default=setting["demos"], help="oracle demonstrations to train on")
    parser.add_argument(
        "--steps", type=int, default=setting["steps"], help="training steps (with --minutes: at most this many)"
    )
    parser.add_argument(
        "--minutes",
        type=float,
        default=setting.get("train_minutes", 0.0),
        help="train for this many minutes (checks and saves included) instead of a fixed step count; 0: --steps",
    )
    parser.add_argument(
        "--check-every",
        type=int,
        default=setting.get("check_every", 0),
        help="steps between checks on held-out validation scenes while training (the best one is tested); 0: none",
    )
    parser.add_argument(
        "--check-scenes", type=int, default=setting.get("check_scenes", 0), help="validation scenes of each check"
    )
    parser.add_argument(
        "--check-start",
        type=int,
        default=setting.get("check_start", 0),
        help="the first step a check may come at (0: --check-every); the last step is always checked",
    )
    parser.add_argument("--episodes", type=int, default=setting["episodes"], help="test episodes")
    parser.add_argument(
        "--swap-scenes",
        type=int,
        default=setting.get("swap_scenes", 0),
        help="test scenes on which instruction following is measured (each gives one swap per other block)",
    )
    taken: set[str] = set()
    run = parser.add_argument_group("run (defaults: configs/quickstart.toml)")
    add_flags(
        run,
        [TrainConfig],
        only=RUN_FLAGS,
        taken=taken,
        extra={
            "agent": {"choices": agent_names()},
            "recipe": {"choices": recipe_names()},
            "every_instruction": {
                "help": "record every instruction of each demo scene with the oracle's action for it, and train on "
                "all of them"
            },
            "pair_contrasts": {
                "help": "follow each training sample by its scene under an instruction naming another block and "
                "another bowl (needs --every-instruction; default: on where it is)"
            },
        },
    )
    add_flags(run, [EnvConfig], only=["camera_scale"], taken=taken)
    add_flags(
        parser.add_argument_group("agent (defaults: configs/quickstart.toml)"),
        config_classes(),
        only=LESSON_AGENT_FLAGS,
        taken=taken,
        extra={
            "n_rotations": {
                "help": "place rotations (default: 1 where the task's place yaw says nothing, else the agent's 36; "
                "cliport.train.run_defaults)"
            },
            "clip_weights": {
                "help": "CLIP's weights for agents that use CLIP: 'auto' (the published ones where they can be had, "
                "else seeded random ones, said and recorded), 'openai', 'random' or a file"
            },
        },
    )
    fields = [name for name in (*RUN_FLAGS, *LESSON_AGENT_FLAGS, "camera_scale") if name not in DECIDED_LATER]
    parser.set_defaults(**{name: setting.get(name, FLAG_FALLBACKS.get(name)) for name in fields})
    agent_dests = add_flags(
        parser.add_argument_group("other agent settings (configs/<agent>.toml)"),
        config_classes(),
        "agent_config",
        skip=LESSON_AGENT_FLAGS,
        taken=taken,
    )
    return parser, agent_dests


def parse_args(device: str, argv: list[str] | None = None) -> Any:
    early = argparse.ArgumentParser(add_help=False)
    early.add_argument("--language", action="store_true")
    language = early.parse_known_args(argv)[0].language
    setting = device_defaults("quickstart", device, "language" if language else None)
    parser, agent_dests = build_parser(setting, language)
    args = parser.parse_args(argv)
    args.agent_settings = given_flags(args, agent_dests).get("agent_config", {})
    for name in ("demos", "steps", "batch_size", "episodes"):
        if getattr(args, name) < 1:
            raise ConfigError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    for name in ("minutes", "check_every", "check_scenes", "check_start"):
        if getattr(args, name) < 0:
            raise ConfigError(f"--{name.replace('_', '-')} must be at least 0, got {getattr(args, name)}")
    if not 0 <= args.lr_cooldown <= 1:
        raise ConfigError(f"--lr-cooldown is a fraction of the training, from 0 to 1, got {args.lr_cooldown}")
    args.aims = setting.get("aims")
    args.measured_steps = setting.get("measured_steps", 0)
    if args.pair_contrasts is None:  # on by default where there are a scene's instructions to pair
        args.pair_contrasts = bool(setting.get("pair_contrasts", False)) and args.every_instruction
    tasks.resolve(args.task)
    for name in args.test_task:
        lesson_task(name, "test", "--test-task")
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
    from cliport.models.encoders.clip_registry import MODEL_NAME
    from cliport.models.encoders.clip_weights import published_weights_available

    if published_weights_available(model_name=getattr(args, "semantic_encoder", None) or MODEL_NAME):
        return "openai"
    print(
        "CLIP weights: the published ones cannot be had here (not in the Hugging Face cache, no network), so this "
        "run uses seeded RANDOM CLIP weights (recorded in results.json); pass --clip-weights PATH for a file",
        file=sys.stderr,
    )
    return "random"


def train_config(args: Any, data_dir: str, run_dir: str, clip: str | None, check_saved: bool = True) -> TrainConfig:
    """The run's config: the quickstart's settings, with the place rotations and renderer of
    :func:`~cliport.train.run_defaults.run_defaults` (as cliport-train resolves them; ``--n-rotations`` wins)."""
    agent_config: dict[str, Any] = {"width": args.width, "map_scale": args.map_scale}
    if args.lr is not None:
        agent_config["lr"] = args.lr
    if clip is not None:
        agent_config["clip_weights"] = clip
        if args.semantic_encoder:
            agent_config["semantic_encoder"] = args.semantic_encoder
    if agent_class(args.agent).uses_language:
        agent_config["center_sentences"] = args.center_sentences
        agent_config["scale_up_mid"] = args.scale_up_mid
    agent_config.update(args.agent_settings)
    given = {
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
        "time_budget_s": args.minutes * 60,
        "lr_cooldown": args.lr_cooldown,
        "num_workers": 1,
        "every_instruction": args.every_instruction,
        "pair_contrasts": args.pair_contrasts,
        "agent_config": agent_config,
        "env": {"camera_scale": args.camera_scale},
    }
    config = TrainConfig.build(merge(given, run_defaults(args.task, n_rotations=args.n_rotations).overrides()))
    if check_saved and os.path.exists(os.path.join(run_dir, "config.json")):
        saved = load_run_config(run_dir).to_dict()
        changed = sorted(k for k, v in config.to_dict().items() if saved.get(k) != v)
        if changed:
            raise RunDirError(
                f"{run_dir} holds a quickstart run with other settings ({', '.join(changed)}): "
                "pass another --out, or delete that folder"
            )
    return config


def machine_speed(config: TrainConfig, args: Any, device: str) -> dict[str, Any]:
    """Time a few training steps of the run's agent on a synthetic batch and say what that means for the run (the
    lesson's first line)."""
    seconds = step_seconds(config)
    kernels = torch.backends.cpu.get_cpu_capability() if device == "cpu" else torch.cuda.get_device_name()
    where = f"{torch.get_num_threads()} CPU threads, {kernels} kernels" if device == "cpu" else kernels
    if args.minutes > 0:
        steps, means = budget_means(seconds, args.minutes, args.steps, args.measured_steps)
    else:
        steps = args.steps
        means = f"so {args.steps} steps take about {args.steps * seconds / 60:.1f} minutes"
    print(f"machine: {where}; a training step takes {seconds:.2f} s, {means}")
    return {"device": where, "probe_step_s": round(seconds, 3), "expected_steps": steps}


def budget_means(seconds: float, minutes: float, max_steps: int, measured_steps: int = 0) -> tuple[int, str]:
    """The steps a ``minutes`` training budget fits at ``seconds`` a step, and what to say of it; where that is under
    ``measured_steps`` (the fewest the lesson's aims were measured to hold at), the ``--minutes`` that trains them
    (the checks and saves take about 5 % besides the steps)."""
    steps = min(max_steps, int(minutes * 60 / seconds))
    means = f"so the {minutes:g}-minute training budget fits about {steps} steps (at most {max_steps})"
    if steps < measured_steps <= max_steps:  # a --steps under measured_steps is the user's choice
        enough = math.ceil(measured_steps * seconds * 1.05 / 30) / 2
        return steps, (
            f"{means}: fewer than the {measured_steps} the lesson's aims were measured at; --minutes {enough:g} "
            "trains about that many here (docs/language-lesson.md#when-a-run-misses-the-aims)"
        )
    return steps, f"{means}; a slower machine trains fewer steps in the same time (docs/language-lesson.md)"


def held_out_check(args: Any) -> HeldOutCheck:
    """The lesson's checks on held-out validation scenes while it trains (``--check-every``, ``--check-scenes``,
    ``--check-start``)."""
    scenes = record_scenes(args.task, args.check_scenes, args.camera_scale)
    return HeldOutCheck(scenes, args.check_every, start=args.check_start or args.check_every)


def aims_verdict(aims: dict[str, float], result: dict[str, Any], following: dict[str, Any], total_s: float) -> dict:
    """Whether the run met the lesson's aims (``[language.aims]``): solved and followed rates, minutes."""
    solved = result["success_rate"]
    got = {"solved": solved, "followed": following["rate"], "minutes": total_s / 60}
    missed = [
        f"{name} {100 * got[name]:.0f} % (aim {100 * aims[name]:.0f} %)"
        for name in ("solved", "followed")
        if got[name] < aims[name]
    ]
    if got["minutes"] > aims["minutes"]:
        missed.append(f"{got['minutes']:.1f} minutes (aim {aims['minutes']:g})")
    head = (
        f"The lesson's aims (at least {100 * aims['solved']:.0f} % solved, {100 * aims['followed']:.0f} % of swaps "
        f"followed, within {aims['minutes']:g} minutes): "
    )
    return {**got, "met": not missed, "line": head + ("met." if not missed else "not met: " + "; ".join(missed) + ".")}


def main() -> None:
    device = "cuda" if torch.cuda.is_available() else "cpu"
    args = parse_args(device)
    data_dir, run_dir = os.path.join(args.out, "data"), os.path.join(args.out, "run")
    timings: dict[str, float] = {}
    start = time.perf_counter()
    machine = None
    if args.language:  # the first line: this machine's speed (the weights' values do not change it)
        probe_clip = "random" if "clip_weights" in agent_class(args.agent).weight_sources else None
        probe = train_config(args, data_dir, run_dir, probe_clip, check_saved=False)
        machine = machine_speed(probe, args, device)
    clip = resolve_clip_weights(args)
    config = train_config(args, data_dir, run_dir, clip)
    n_rotations = config.agent_config.n_rotations

    every = ", every instruction of each scene" if args.every_instruction else ""
    print(f"1/4 demonstrations: {args.demos} oracle episodes of {args.task}{every}")
    demo_config = DemoConfig.defaults(
        data_dir=data_dir, camera_scale=args.camera_scale, every_instruction=args.every_instruction
    )
    demos = generate(args.task, "train", args.demos, demo_config)
    timings["demos_s"] = time.perf_counter() - start

    weights = f", CLIP weights {clip}" if clip is not None else ""
    weights += ", centred sentence features" if args.center_sentences else ""
    weights += ", contrasting pairs" if args.pair_contrasts else ""
    print(
        f"2/4 training {args.agent} on {device} with the {args.recipe} recipe (width {args.width}, map scale "
        f"{args.map_scale}, {n_rotations} place rotation(s), batch {args.batch_size}{weights}) for "
        + (f"{args.minutes:g} minutes (at most {args.steps} steps)" if args.minutes > 0 else f"{args.steps} steps")
    )
    run = RunDir(run_dir)
    mark = time.perf_counter()
    checked = args.check_every > 0 and args.check_scenes > 0
    # An earlier run trained every step: its time and start draws are not read back from the checkpoints.
    trained: dict[str, Any] = {"step": args.steps, "trained_s": None, "init_draws": None}
    if args.minutes > 0 or not os.path.exists(run.checkpoint(args.steps)):
        check = held_out_check(args) if checked else None
        done = train(config, resume=run.is_run(), check=check)  # a finished run returns at once
        trained = {"step": done["steps"], "trained_s": done["trained_s"], "init_draws": done["init_draws"]}
    timings["training_s"] = time.perf_counter() - mark
    tested = run.best_step() if checked else None
    which = f"the step-{tested} checkpoint, the best held-out check" if tested is not None else "the last checkpoint"
    print(f"    trained {trained['step']} steps in {(trained['trained_s'] or timings['training_s']) / 60:.1f} minutes")

    print(f"3/4 evaluating {which} on {args.episodes} test episodes")
    mark = time.perf_counter()
    agent = PickPlaceAgent.from_pretrained(run.checkpoint(tested if tested is not None else "last"), device=device)
    result = evaluate(agent, args.task, "test", args.episodes, camera_scale=args.camera_scale)
    solved = [row for row in result["episodes"] if row["total_reward"] > 0.99]
    following = None
    if args.swap_scenes > 0:
        seeds = [row["seed"] for row in result["episodes"]][: args.swap_scenes]
        following = instruction_following(agent, args.task, seeds, args.camera_scale)
        print(f"    instruction following: {following['followed']} of {following['n']} swapped instructions")
    other_tests = {}
    for name in args.test_task:
        other_tests[name] = colour_report(agent, name, args.episodes, args.swap_scenes, args.camera_scale)
        other_solved, unseen = other_tests[name]["test"]["solved"], other_tests[name]["unseen_named"]
        print(
            f"    {name}: solved {other_solved} of {args.episodes}; naming an unseen colour: solved "
            f"{unseen['solved']} of {unseen['episodes']}, swaps followed {unseen['followed']} of {unseen['swaps']}"
        )
        groups = other_tests[name]["by_named"].items()
        print("      unseen word: " + "; ".join(
            f"{group.removesuffix('_unseen')}: solved {part['solved']}/{part['episodes']}, "
            f"followed {part['followed']}/{part['swaps']}" for group, part in groups
        ))  # fmt: skip
    timings["evaluation_s"] = time.perf_counter() - mark
    with contextlib.closing(summary_writer(os.path.join(run_dir, "eval", "tensorboard"))) as tensorboard:
        log_result(tensorboard, f"eval/{args.task}/test", result, trained["step"])  # beside training's curves

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
        "environment": measurement_environment(),
        "demos": {k: demos[k] for k in ("saved", "skipped_existing", "demos_per_minute", "mb_per_step")},
        "training": {
            "agent": args.agent,
            "recipe": args.recipe,
            "steps": trained["step"],
            "max_steps": args.steps,
            "minutes": args.minutes,
            "trained_s": trained["trained_s"],
            "tested_step": tested if tested is not None else trained["step"],
            "held_out": read_json(run.held_out) if os.path.exists(run.held_out) else None,
            "width": args.width,
            "map_scale": args.map_scale,
            "lr": agent.config.lr,
            "lr_cooldown": args.lr_cooldown,
            "n_rotations": n_rotations,
            "batch_size": args.batch_size,
            "seed": args.seed,
            "init_draws": trained["init_draws"],
            "clip_weights": clip,
            "semantic_encoder": args.semantic_encoder,
            "every_instruction": args.every_instruction,
            "pair_contrasts": args.pair_contrasts,
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
    if machine is not None:
        summary["machine"] = machine
    if other_tests:
        summary["other_tests"] = other_tests
    if following is not None:
        summary["instruction_following"] = {k: following[k] for k in ("rate", "n", "followed", "swaps")}
        summary["two_instructions"] = figure
    write_json(os.path.join(args.out, "results.json"), summary)
    print(json.dumps({k: v for k, v in summary.items() if k not in ("instruction_following", "other_tests")}, indent=2))
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
    if args.aims and following is not None:
        summary["aims"] = aims_verdict(args.aims, result, following, timings["total_s"])
        write_json(os.path.join(args.out, "results.json"), summary)
        print(summary["aims"]["line"])


if __name__ == "__main__":
    run_cli(main)
