"""Colour transfer: how an agent trained on the seen colours of put-one-block-in-bowl does on scenes and
instructions of the colours its demonstrations never showed (CLIPort's ``-unseen-colors`` split).

put-one-block-in-bowl-unseen-colors draws its test scenes' five colours from CLIPort's evaluation palette,
four of whose seven colours (orange, purple, pink, white) no training demo of the seen split holds; the other
three (blue, red, green) are seen ones. So :func:`colour_report` splits what it measures by the colours named:
episodes whose instruction names an unseen block or bowl colour, and swapped instructions naming an unseen block,
against the rest, and both of them finer by which of the two words is unseen (:data:`NAMED_GROUPS`); it also says
which colours the scenes used, so a report shows that the split is what it claims.
"""

from __future__ import annotations

from typing import Any

from cliport.evaluation.evaluate import confidence_interval, evaluate
from cliport.evaluation.instruction_following import instruction_following, lesson_task
from cliport.pretrain.vocabulary import COLOR_NAMES, UNSEEN_COLORS


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


#: What an instruction's two colour words are, by which of them is unseen: the block's, the bowl's, both, neither.
NAMED_GROUPS = ("block_unseen", "bowl_unseen", "both_unseen", "neither_unseen")


def named_group(block: str, bowl: str) -> str:
    """The :data:`NAMED_GROUPS` entry of an instruction naming ``block`` and ``bowl``."""
    block_unseen, bowl_unseen = block in UNSEEN_COLORS, bowl in UNSEEN_COLORS
    if block_unseen and bowl_unseen:
        return "both_unseen"
    return "block_unseen" if block_unseen else "bowl_unseen" if bowl_unseen else "neither_unseen"


def named_colors(instruction: str) -> tuple[str, str]:
    """The block and bowl colours an instruction names, the first and last colour words ("put the pink blocks in a
    green bowl" -> ("pink", "green")); ValueError where it names none."""
    words = [w for w in instruction.lower().replace(",", " ").replace(".", " ").split() if w in COLOR_NAMES]
    if not words:
        raise ValueError(f"the instruction {instruction!r} names no colour")
    return words[0], words[-1]


def score_by_named(result: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """An evaluation result (:func:`~cliport.evaluation.evaluate.summarise`; each episode with its
    ``instruction``) split by :func:`named_group` of the block and bowl colours its instructions name: per group,
    ``episodes``, ``mean_score`` (mean total reward x100) with its 95 % interval and ``solved``."""
    groups: dict[str, list[float]] = {name: [] for name in NAMED_GROUPS}
    for episode in result["episodes"]:
        if "instruction" not in episode:
            raise ValueError(f"episode {episode['seed']} records no instruction (evaluated before they were kept)")
        groups[named_group(*named_colors(episode["instruction"]))].append(100 * episode["total_reward"])
    return {
        name: {**_mean_score(scores), "solved": sum(score > 99 for score in scores)} for name, scores in groups.items()
    }


def _mean_score(scores: list[float]) -> dict[str, Any]:
    """``episodes``, ``mean_score`` and its 95 % interval ``ci95`` of scores in [0, 100]; None where there are none."""
    if not scores:
        return {"episodes": 0, "mean_score": None, "ci95": None}
    low, high = confidence_interval(scores)
    return {
        "episodes": len(scores),
        "mean_score": round(sum(scores) / len(scores), 2),
        "ci95": [round(low, 2), round(high, 2)],
    }


def _rate(hits: int, n: int) -> float | None:
    return round(hits / n, 4) if n else None


def _with_rates(counts: dict[str, int]) -> dict[str, Any]:
    return {
        **counts,
        "solved_rate": _rate(counts["solved"], counts["episodes"]),
        "followed_rate": _rate(counts["followed"], counts["swaps"]),
    }


def split_by_colour(
    solved: dict[int, bool], colors: dict[int, dict[str, Any]], swaps: list[dict[str, Any]]
) -> dict[str, dict[str, Any]]:
    """Episodes (seed -> solved) and swaps (each with its scene's ``seed``) split by the colours named:
    ``unseen_named`` (an episode whose instruction names an unseen block or bowl colour; a swap naming an unseen
    block) and ``seen_named`` (the rest), and ``by_named``: both split by :func:`named_group` of the block and bowl
    the instruction names (a swap names its block and keeps the scene's bowl). Each part holds counts and rates."""
    unseen = set(UNSEEN_COLORS)
    empty = {"episodes": 0, "solved": 0, "swaps": 0, "followed": 0}
    split = {name: dict(empty) for name in ("unseen_named", "seen_named")}
    by_named = {name: dict(empty) for name in NAMED_GROUPS}
    for seed, ok in solved.items():
        block, bowl = colors[seed]["goal_block"], colors[seed]["goal_bowl"]
        for group in (
            split["unseen_named" if {block, bowl} & unseen else "seen_named"],
            by_named[named_group(block, bowl)],
        ):
            group["episodes"] += 1
            group["solved"] += int(ok)
    for swap in swaps:
        bowl = colors[swap["seed"]]["goal_bowl"]
        for group in (
            split["unseen_named" if swap["named"] in unseen else "seen_named"],
            by_named[named_group(swap["named"], bowl)],
        ):
            group["swaps"] += 1
            group["followed"] += int(swap["followed"])
    return {
        **{name: _with_rates(counts) for name, counts in split.items()},
        "by_named": {name: _with_rates(counts) for name, counts in by_named.items()},
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

    Returns ``test`` (solved of all episodes), ``following`` (of all swaps), ``unseen_named``, ``seen_named`` and
    ``by_named``, ``scenes`` (:func:`scenes_summary`) and the ``swaps`` themselves.
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
