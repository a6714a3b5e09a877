"""Colour transfer: how an agent trained on the seen colours of put-one-block-in-bowl does on scenes and
instructions of the colours its demonstrations never showed (CLIPort's ``-unseen-colors`` split).

put-one-block-in-bowl-unseen-colors draws its test scenes' five colours from CLIPort's evaluation palette,
four of whose seven colours (orange, purple, pink, white) no training demo of the seen split holds; the other
three (blue, red, green) are seen ones. So :func:`colour_report` splits what it measures by the colours named:
episodes whose instruction names an unseen block or bowl colour, and swapped instructions naming an unseen block,
against the rest; it also says which colours the scenes used, so a report shows that the split is what it claims.
"""

from __future__ import annotations

from typing import Any

from cliport.evaluation.evaluate import evaluate
from cliport.evaluation.instruction_following import instruction_following, lesson_task
from cliport.pretrain.vocabulary import UNSEEN_COLORS


def scene_colors(task_name: str, seeds: list[int], camera_scale: float = 1.0, mode: str = "test") -> dict[int, Any]:
    """Each scene's colours: seed -> ``{"goal_block", "goal_bowl", "blocks", "bowls"}`` (a put-one-block-in-bowl-*
    task, reset once per seed; about a third of a second a scene)."""
    from cliport.env.environment import EnvConfig, Environment

    task = lesson_task(task_name, mode, "the colour report")
    out = {}
    with Environment(EnvConfig.defaults(camera_scale=camera_scale), task=task) as env:
        for seed in seeds:
            env.reset(seed=seed)
            out[int(seed)] = {
                "goal_block": task.goal_block,
                "goal_bowl": task.goal_bowl,
                "blocks": list(task.block_colors),
                "bowls": list(task.bowl_colors),
            }
    return out


def _rate(hits: int, n: int) -> float | None:
    return round(hits / n, 4) if n else None


def split_by_colour(
    solved: dict[int, bool], colors: dict[int, dict[str, Any]], swaps: list[dict[str, Any]]
) -> dict[str, dict[str, Any]]:
    """Episodes (seed -> solved) and swaps split by the colours named: ``unseen_named`` (an episode whose instruction
    names an unseen block or bowl colour; a swap naming an unseen block) and ``seen_named`` (the rest), each with
    counts and rates."""
    unseen = set(UNSEEN_COLORS)
    split = {name: {"episodes": 0, "solved": 0, "swaps": 0, "followed": 0} for name in ("unseen_named", "seen_named")}
    for seed, ok in solved.items():
        named = {colors[seed]["goal_block"], colors[seed]["goal_bowl"]}
        group = split["unseen_named" if named & unseen else "seen_named"]
        group["episodes"] += 1
        group["solved"] += int(ok)
    for swap in swaps:
        group = split["unseen_named" if swap["named"] in unseen else "seen_named"]
        group["swaps"] += 1
        group["followed"] += int(swap["followed"])
    return {
        name: {
            **counts,
            "solved_rate": _rate(counts["solved"], counts["episodes"]),
            "followed_rate": _rate(counts["followed"], counts["swaps"]),
        }
        for name, counts in split.items()
    }


def scenes_summary(colors: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """Which colours the scenes used, which of them are unseen, and how many scenes held an unseen one."""
    unseen = set(UNSEEN_COLORS)
    used = sorted({c for scene in colors.values() for c in scene["blocks"] + scene["bowls"]})
    return {
        "colors_used": used,
        "unseen_colors_used": [c for c in used if c in unseen],
        "with_an_unseen_color": sum(bool(set(s["blocks"] + s["bowls"]) & unseen) for s in colors.values()),
        "n": len(colors),
    }


def colour_report(
    agent: Any, task_name: str, n_episodes: int, swap_scenes: int, camera_scale: float = 1.0
) -> dict[str, Any]:
    """Test episodes and swapped instructions (:func:`~cliport.evaluation.instruction_following.instruction_following`)
    of ``task_name`` (put-one-block-in-bowl-seen-colors or -unseen-colors), split by whether the colours named are
    among :data:`~cliport.pretrain.vocabulary.UNSEEN_COLORS` (:func:`split_by_colour`).

    Returns ``test`` (solved of all episodes), ``following`` (of all swaps), ``unseen_named`` and ``seen_named``,
    ``scenes`` (:func:`scenes_summary`) and the ``swaps`` themselves.
    """
    result = evaluate(agent, task_name, "test", n_episodes, camera_scale=camera_scale)
    seeds = [int(row["seed"]) for row in result["episodes"]]
    solved = {int(row["seed"]): row["total_reward"] > 0.99 for row in result["episodes"]}
    colors = scene_colors(task_name, seeds, camera_scale)
    following = instruction_following(agent, task_name, seeds[:swap_scenes], camera_scale)
    n_solved = sum(solved.values())
    return {
        "task": task_name,
        "test": {"episodes": len(seeds), "solved": n_solved, "rate": _rate(n_solved, len(seeds))},
        "following": {k: following[k] for k in ("rate", "n", "followed")},
        **split_by_colour(solved, colors, following["swaps"]),
        "scenes": scenes_summary(colors),
        "swaps": following["swaps"],
    }
