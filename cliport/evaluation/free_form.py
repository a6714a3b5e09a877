"""One episode with a free-form instruction: a video and the pick/place heatmaps of every action."""

from __future__ import annotations

import hashlib
import os
import re
import sys
from typing import Any

from cliport.data.rollout import run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.evaluation.evaluate import agent_policy
from cliport.evaluation.visualize import action_panel, save_png, save_video
from cliport.utils.files import write_json


def instruction_slug(lang: str, max_words: int = 6) -> str:
    """A file-name part unique to an instruction: its first words and a short hash of the whole text."""
    words = re.findall(r"[a-z0-9]+", lang.lower())[:max_words]
    digest = hashlib.sha1(lang.encode()).hexdigest()[:8]
    return "-".join([*words, digest])


def run_instruction(
    agent: Any,
    task_name: str,
    mode: str,
    seed: int,
    lang: str,
    out_dir: str,
    camera_scale: float = 1.0,
    renderer: str | None = None,
) -> dict[str, Any]:
    """Reset ``task_name`` with ``seed`` and act with ``lang`` in place of the task's instructions, rendering with
    ``renderer`` (the workcell setting; None: ``configs/env.toml``'s)."""
    from cliport import tasks

    notes = []
    if not agent.uses_language:
        notes.append(f"{agent.name} ignores language: the instruction cannot change what it does")
    elif agent.encoder is not None and (note := agent.encoder.instruction_note(lang)) is not None:
        notes.append(note)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    os.makedirs(out_dir, exist_ok=True)
    stem = f"{task_name}-seed{seed}-{instruction_slug(lang)}"
    panels: list[str] = []

    def on_act(obs: dict[str, Any], result: dict[str, Any], instruction: str | None) -> None:
        path = os.path.join(out_dir, f"{stem}-step{len(panels) + 1}-heatmaps.png")
        similarity = agent.similarity_heatmaps(obs, instruction) if instruction else {}
        save_png(path, action_panel(obs, result, instruction, similarity=similarity))
        panels.append(path)

    with Environment(
        EnvConfig.defaults(camera_scale=camera_scale, renderer=renderer), task=tasks.make(task_name, mode)
    ) as env:
        env.start_recording()
        episode = run_episode(env, seed, agent_policy(agent, lang=lang, on_act=on_act))
        frames = env.stop_recording()
    video = os.path.join(out_dir, f"{stem}.gif")
    save_video(video, frames)
    result = {
        "task": task_name,
        "seed": seed,
        "instruction": lang,
        **agent.describe(),
        "actions": episode.n_actions,
        "task_reward": round(episode.total_reward, 4),
        "video": video,
        "heatmaps": panels,
        "notes": notes,
    }
    write_json(os.path.join(out_dir, f"{stem}.json"), result)
    return result
