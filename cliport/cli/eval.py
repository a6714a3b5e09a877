"""cliport-eval: evaluate a trained agent, or try a free-form instruction and see its heatmaps."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys

from cliport.cli.common import OneLineParser, add_weight_flags, run_cli, weight_overrides
from cliport.errors import CheckpointError, ConfigError


def _parser() -> tuple[argparse.ArgumentParser, list[str]]:
    from cliport.evaluation.evaluate import EvalConfig
    from cliport.utils.config import add_flags

    parser = OneLineParser(
        prog="cliport-eval",
        description="Evaluate checkpoints of a training run on val/test episodes, or run one episode with "
        "--lang and save a video and the pick/place heatmaps. Defaults come from configs/eval.toml.",
    )
    parser.add_argument("--run-dir", required=True, help="a cliport-train run folder, or hf://org/name[@revision]")
    dests = add_flags(parser, [EvalConfig])
    parser.add_argument("--task", help="default: the run's task")
    parser.add_argument("--agent", help="expected agent of the checkpoint (checked)")
    parser.add_argument("--lang", help="one episode with this instruction instead of the task's own")
    parser.add_argument("--seed", type=int, help="with --lang: the scene's seed (default: first seed of --mode)")
    parser.add_argument("--video", action="store_true", help="record a GIF of every evaluation episode")
    parser.add_argument("--out", help="output folder (default: RUN/eval)")
    add_weight_flags(parser)
    parser.add_argument("--no-progress", action="store_true")
    return parser, dests


def checkpoints_to_run(run_dir: str, which: str) -> list[int | str]:
    """The checkpoints ``--checkpoint`` names: best (from val.json), last, all, or one saved step."""
    from cliport.utils.run_dir import RunDir

    run = RunDir(run_dir)
    return run.resolve(which, run.best_step() if which == "best" else None)


def main(argv: list[str] | None = None) -> None:
    parser, dests = _parser()
    args = parser.parse_args(argv)
    from cliport import tasks
    from cliport.agents import PickPlaceAgent
    from cliport.data.seeds import episode_seeds
    from cliport.deploy.hub import hub_eval_dir
    from cliport.env.environment import RENDERER_KINDS, EnvConfig
    from cliport.evaluation.engine import EvalEngine, resolve_workers
    from cliport.evaluation.evaluate import EvalConfig, evaluate
    from cliport.train.config import load_run_config
    from cliport.train.run_defaults import run_defaults
    from cliport.utils.config import given_flags, load
    from cliport.utils.device import resolve_device
    from cliport.utils.files import read_json, write_json
    from cliport.utils.hub import HF_PREFIX, resolve_run_dir
    from cliport.utils.machine import measurement_environment
    from cliport.utils.run_dir import RunDir
    from cliport.utils.tensorboard import log_result, summary_writer

    config = load(EvalConfig, "eval", given_flags(args, dests))
    if args.lang is not None and not args.lang.strip():
        raise ConfigError("--lang must be a non-empty instruction")
    if config.n_episodes < 1:
        raise ConfigError(f"--n-episodes must be >= 1, got {config.n_episodes}")
    if config.mode not in ("val", "test"):
        raise ConfigError(f"--mode must be val or test, got {config.mode!r}")
    workers = resolve_workers(config.workers, 1 if args.lang is not None else config.n_episodes)
    source, args.run_dir = args.run_dir, resolve_run_dir(args.run_dir)
    run_config = load_run_config(args.run_dir)
    run = RunDir(args.run_dir)
    camera_scale = config.camera_scale or run_config.env.camera_scale
    if camera_scale != run_config.env.camera_scale:
        print(
            f"note: rendering at camera scale {camera_scale}; the run's demos and validation used "
            f"{run_config.env.camera_scale}",
            file=sys.stderr,
        )
    renderer = run_defaults(run_config.task, renderer=config.renderer, saved=run_config).renderer
    validated_with = read_json(run.val).get("renderer") if os.path.exists(run.val) else None
    names = tasks.resolve(args.task or run_config.task)
    out = args.out or (hub_eval_dir(source) if source.startswith(HF_PREFIX) else run.eval_dir)
    device = resolve_device(config.device)
    weights = weight_overrides(args)
    engines: dict[str, EvalEngine] = {}  # one per task, its workers kept across checkpoints (--checkpoint all)
    env_config = EnvConfig.defaults(camera_scale=camera_scale, renderer=renderer)
    events, tensorboard = os.path.join(out, "tensorboard"), None  # the summaries as TensorBoard scalars
    with contextlib.ExitStack() as stack:
        for which in checkpoints_to_run(args.run_dir, config.checkpoint):
            path = run.checkpoint(which)
            agent = PickPlaceAgent.from_pretrained(path, device=device, weights=weights)
            if args.agent is not None and agent.name != args.agent:
                raise CheckpointError(f"{path} is a checkpoint of agent {agent.name!r}, not {args.agent!r}")
            if args.lang is not None:
                from cliport.evaluation.free_form import run_instruction

                seed = args.seed if args.seed is not None else episode_seeds(config.mode, 1)[0]
                result = run_instruction(agent, names[0], config.mode, seed, args.lang, out, camera_scale, renderer)
                print(json.dumps(result, indent=2))
                return
            for name in names:
                if name not in engines:
                    engine = EvalEngine(name, config.mode, env_config, workers, not args.no_progress)
                    engines[name] = stack.enter_context(engine)
                for other, engine in engines.items():
                    if other != name:
                        engine.close()  # a group: one task's workers at a time (restarted when needed)
                video_dir = os.path.join(out, "videos") if args.video else None
                result = evaluate(
                    agent,
                    name,
                    config.mode,
                    config.n_episodes,
                    video_dir=video_dir,
                    video_fps=config.video_fps,
                    engine=engines[name],
                )
                if validated_with in RENDERER_KINDS and result["renderer"] != validated_with:
                    flag = "cpu" if validated_with == "tiny" else "egl"
                    print(
                        f"note: rendered with {result['renderer']}; the run was validated with {validated_with} "
                        f"(their pixels differ; --renderer {flag} renders as validation did)",
                        file=sys.stderr,
                    )
                    validated_with = None  # said once
                result.update(checkpoint=which, checkpoint_file=path, **agent.describe(), run_dir=source)
                result["recipe"] = run_config.recipe  # how the evaluated weights were trained
                result["environment"] = measurement_environment()
                write_json(os.path.join(out, f"{name}-{config.mode}-{which}.json"), result)
                # "last" is drawn at the run's final step (where a finished run's last.pt was saved).
                step = run_config.n_steps if which == "last" else int(which)
                tensorboard = tensorboard or stack.enter_context(contextlib.closing(summary_writer(events)))
                log_result(tensorboard, f"eval/{name}/{config.mode}", result, step)
                summary = {k: v for k, v in result.items() if k != "episodes"}
                print(json.dumps(summary))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
