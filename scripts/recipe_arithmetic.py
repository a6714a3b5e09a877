"""Print JSON: what each training recipe's loss does to the first Adam step of a default-initialised agent.

For one oracle sample of a task (simulator observation, pick and place targets), each recipe's loss is
back-propagated once through a freshly initialised agent (PyTorch's default initialisation, the same for
every recipe) and Adam takes one step. Per net (pick, place) it reports the share of per-parameter
gradients below Adam's epsilon and the mean parameter move |delta| / lr. Adam's first step is
lr * g / (|g| + eps): about lr when |g| >> eps, about lr * |g| / eps when |g| << eps. CLIPort's loss (the
cross-entropy divided by the map's cells) puts nearly every gradient below eps.

    python scripts/recipe_arithmetic.py [--agent transporter_only] [--task block-insertion] [--width 1.0]
"""

from __future__ import annotations

import copy
import json

import numpy as np
import torch

from cliport import tasks
from cliport.agents import make_agent
from cliport.cli.common import OneLineParser, run_cli
from cliport.env.environment import EnvConfig, Environment
from cliport.train.recipes import get_recipe, recipe_names


def _sample(task: str, seed: int) -> dict[str, object]:
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=tasks.make(task, "train")) as env:
        obs = env.reset(seed=seed)
        action = env.task.oracle_act(obs)
    return {
        "color": obs["color"][None],
        "height": obs["height"][None],
        "pose0": np.concatenate(action["pose0"])[None],
        "pose1": np.concatenate(action["pose1"])[None],
        "lang": [None],
    }


def main() -> None:
    parser = OneLineParser(prog="recipe_arithmetic.py", description=__doc__.splitlines()[0])
    parser.add_argument("--agent", default="transporter_only")
    parser.add_argument("--task", default="block-insertion")
    parser.add_argument("--width", type=float, default=1.0)
    parser.add_argument("--n-rotations", type=int, default=36)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    tasks.resolve(args.task)
    batch = _sample(args.task, args.seed)
    torch.manual_seed(args.seed)
    initial = make_agent(args.agent, {"width": args.width, "n_rotations": args.n_rotations})
    out: dict[str, object] = {"agent": args.agent, "task": args.task, "width": args.width, "recipes": {}}
    for name in recipe_names():
        recipe = get_recipe(name)
        agent = copy.deepcopy(initial)
        before = {n: p.detach().clone() for n, p in agent.named_parameters() if p.requires_grad}
        optimizer, _ = recipe.prepare(agent)
        agent.train()
        optimizer.zero_grad()
        loss, info = agent.compute_loss(batch, recipe.loss)
        loss.backward()
        grads = {n: p.grad.detach().abs().flatten() for n, p in agent.named_parameters() if p.grad is not None}
        optimizer.step()
        row: dict[str, object] = {"loss": float(loss), "pick_ce": info["pick_loss"], "place_ce": info["place_loss"]}
        for net in ("pick", "place"):
            g = torch.cat([v for n, v in grads.items() if n.startswith(net + ".")])
            moved = torch.cat([(p.detach() - before[n]).abs().flatten() for n, p in agent.named_parameters()
                               if n in before and n.startswith(net + ".")])  # fmt: skip
            row[net] = {
                "share_of_gradients_below_eps": round(float((g < recipe.adam_eps).float().mean()), 4),
                "median_abs_gradient": float(g.median()),
                "mean_move_over_lr": round(float(moved.mean()) / agent.config.lr, 4),
            }
        out["recipes"][name] = row  # type: ignore[index]
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    run_cli(main)
