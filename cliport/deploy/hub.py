"""Sharing trained runs on the Hugging Face Hub: a pushed repo IS a run folder.

:func:`build_hub_folder` assembles what ``cliport-push`` uploads (config.json, ``model.safetensors``: the
pushed checkpoint's weights without pickle, val.json, the chosen checkpoints under ``checkpoints/``, the
evaluation JSONs under ``eval/`` and a ``README.md`` model card);
:func:`~cliport.utils.hub.resolve_run_dir` (in :mod:`cliport.utils.hub`, re-exported here) turns
``hf://org/name[@revision]`` into a local folder from the Hugging Face cache (downloading when online), so every
command that reads a run accepts either.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
from typing import Any

from cliport.errors import HubError, RunDirError
from cliport.utils import run_dir as layout
from cliport.utils.files import read_json

# Resolving hf:// names is the utilities' (every layer reads runs); these names stay importable from here.
from cliport.utils.hub import HF_PREFIX, one_line, parse_hub_ref, resolve_run_dir

_TRAINING_STATE = ("trainer",)  # what last.pt holds beyond the agent: optimiser, step, RNG (not pushed)


def hub_eval_dir(text: str) -> str:
    """Where cliport-eval writes results of a Hub run by default: ``eval/org--name[@rev]`` in the working
    folder (never inside the read-only Hugging Face cache)."""
    repo_id, revision = parse_hub_ref(text)
    return os.path.join("eval", repo_id.replace("/", "--") + (f"@{revision}" if revision else ""))


def _chosen_checkpoints(run: layout.RunDir, which: str) -> list[int | str]:
    chosen = run.resolve(which, run.best_step() if which == "best" else None)
    if which == "all" and os.path.exists(run.checkpoint(layout.LAST)):
        chosen.append(layout.LAST)
    return chosen


def _copy_checkpoint(src: str, dst: str) -> dict[str, Any]:
    """Copy a checkpoint without the training state (optimiser, RNG); its payload (training state included)."""
    from cliport.agents import read_checkpoint
    from cliport.utils.files import save_torch

    payload = read_checkpoint(src)
    if any(key in payload for key in _TRAINING_STATE):
        save_torch({k: v for k, v in payload.items() if k not in _TRAINING_STATE}, dst)
    else:
        shutil.copyfile(src, dst)
    return payload


def _main_checkpoint(chosen: list[int | str], best: int | None) -> int | str:
    """The checkpoint whose weights become the repo's ``model.safetensors``: the val-selected one where it is
    pushed, else the newest scheduled one, else ``last``."""
    if best is not None and best in chosen:
        return best
    steps = [s for s in chosen if isinstance(s, int)]  # every one but LAST
    return max(steps) if steps else chosen[0]


def build_hub_folder(run_dir: str, out: str, repo_id: str, which: str = "best") -> str:
    """Write the folder ``cliport-push`` uploads into ``out`` (a run folder in itself) and return it."""
    from cliport.agents.checkpoint import save_weights

    parse_hub_ref(repo_id)
    run = layout.RunDir(run_dir)
    if not os.path.isdir(run_dir):
        raise RunDirError(f"run folder not found: {run_dir}")
    if not run.is_run():
        raise RunDirError(f"{run_dir} is not a training run (no {layout.CONFIG})")
    chosen = _chosen_checkpoints(run, which)
    if os.path.isdir(out) and os.listdir(out):
        raise RunDirError(f"--local-dir {out} is not empty: give a new or empty folder")
    dest = layout.RunDir(out)
    os.makedirs(os.path.join(out, layout.CHECKPOINTS), exist_ok=True)
    shutil.copyfile(run.config, dest.config)
    if os.path.exists(run.val):
        shutil.copyfile(run.val, dest.val)
    payloads = {step: _copy_checkpoint(run.checkpoint(step), dest.checkpoint(step)) for step in chosen}
    main = _main_checkpoint(chosen, run.best_step())
    payload = payloads[main]
    step = main if isinstance(main, int) else payload.get("trainer", {}).get("step")
    save_weights(payload, dest.model_weights, step=step)  # what from_pretrained("hf://...") reads
    evals = sorted(glob.glob(os.path.join(run.eval_dir, "*.json")))
    if evals:
        os.makedirs(dest.eval_dir, exist_ok=True)
    for path in evals:
        shutil.copyfile(path, os.path.join(dest.eval_dir, os.path.basename(path)))
    card = model_card(read_json(run.config), read_json(run.val) if os.path.exists(run.val) else None,
                      [read_json(p) for p in evals], payload, chosen, repo_id)  # fmt: skip
    with open(os.path.join(out, "README.md"), "w") as f:
        f.write(card)
    return out


def _weight_source_line(field: str, source: Any) -> str:
    text = f"- `{field}`: `{source}`"
    if isinstance(source, str) and (os.path.isabs(source) or os.path.exists(source)):
        text += f" (a local file, not in this repo: pass `--{field.replace('_', '-')} PATH` when loading)"
    elif source == "random":
        text += " (random weights: an offline smoke test, not a trained model)"
    return text


def model_card(
    config: dict[str, Any],
    val: dict[str, Any] | None,
    evals: list[dict[str, Any]],
    payload: dict[str, Any],
    chosen: list[int | str],
    repo_id: str,
) -> str:
    """The README.md of a pushed run: YAML front matter, what it is, its scores and how to use it."""
    agent, task = config.get("agent", "?"), config.get("task", "?")
    main = _main_checkpoint(chosen, val.get("best_step") if val else None)
    tags = ["cliport", "robotics", "pick-and-place", "imitation-learning", str(agent), str(task)]
    lines = ["---", "library_name: cliport", "tags:", *[f"- {t}" for t in dict.fromkeys(tags)], "---", ""]
    lines += [
        f"# {repo_id}",
        "",
        f"A cliport `{agent}` agent trained on `{task}` (CLIPort / Transporter Networks, PyTorch).",
        "",
    ]
    lines += [
        "| | |",
        "|---|---|",
        f"| agent | `{agent}` |",
        f"| task | `{task}` |",
        f"| demos | {config.get('n_demos', '?')} |",
        f"| steps | {config.get('n_steps', '?')} |",
        f"| seed | {config.get('seed', '?')} |",
        f"| checkpoints in this repo | {', '.join(str(s) for s in chosen)} |",
        "",
        "## Pretrained parts",
        "",
    ]
    sources = payload.get("weight_sources") or {}
    if sources:
        lines += [
            "The checkpoints hold only the trained weights; frozen pretrained parts are not included and are "
            "reloaded from these sources:",
            "",
            *[_weight_source_line(k, v) for k, v in sources.items()],
        ]
    else:
        lines.append("None: every weight is trained and in the checkpoints.")
    lines += ["", "## Validation", ""]
    if val and val.get("checkpoints"):
        lines += ["| step | mean val score |", "|---|---|"]
        for step, row in sorted(val["checkpoints"].items(), key=lambda kv: int(kv[0])):
            mark = " (best)" if int(step) == val.get("best_step") else ""
            lines.append(f"| {step}{mark} | {row.get('mean_score')} |")
        lines += ["", f"{val.get('n_episodes', '?')} val episode(s) per checkpoint."]
    else:
        lines.append("No validation results.")
    lines += ["", "## Evaluation", ""]
    if evals:
        lines += [
            "| task | mode | checkpoint | episodes | mean score (95% CI) | success rate |",
            "|---|---|---|---|---|---|",
        ]
        for r in evals:
            ci = r.get("ci95") or ["?", "?"]
            success = r.get("success_rate")
            success = f"{100 * success:.0f}%" if isinstance(success, int | float) else "?"
            lines.append(
                f"| {r.get('task')} | {r.get('mode')} | {r.get('checkpoint')} | {r.get('n_episodes')} | "
                f"{r.get('mean_score')} ({ci[0]}-{ci[1]}) | {success} |"
            )
    else:
        lines.append("Not evaluated yet.")
    # cliport-eval/-predict default to the val-selected checkpoint: name another when it is not here
    pick = "" if val is not None and val.get("best_step") in chosen else f" --checkpoint {chosen[-1]}"
    lines += [
        "",
        "## Use",
        "",
        "```bash",
        f"cliport-eval --run-dir hf://{repo_id}{pick} --mode test --n-episodes 100",
        f'cliport-eval --run-dir hf://{repo_id}{pick} --lang "your instruction" --seed 3',
        f"cliport-predict --run-dir hf://{repo_id}{pick} --rgb c0.png --depth d0.npy --cameras cameras.json "
        '--lang "your instruction" --out predictions/',
        "```",
        "",
        "The repo is a cliport run folder: `hf://org/name[@revision]` works wherever `--run-dir` is read "
        f"(offline: `HF_HUB_OFFLINE=1` after `hf download {repo_id}`).",
        "",
        "```python",
        "from cliport.agents import PickPlaceAgent",
        f'agent = PickPlaceAgent.from_pretrained("hf://{repo_id}")  # model.safetensors, read without pickle',
        "from cliport.deploy import Predictor",
        f'predictor = Predictor("hf://{repo_id}"' + (f', checkpoint="{pick.split()[-1]}"' if pick else "") + ")",
        "```",
        "",
        f"`model.safetensors` holds the trained weights of checkpoint {main} (safetensors: no pickle; the agent, its "
        "config and the pretrained weight sources are in its metadata and `config.json`); "
        "`safetensors.torch.load_file` reads it without cliport.",
        "",
    ]
    return "\n".join(lines)


def upload(folder: str, repo_id: str, private: bool = False) -> str:
    """Create ``repo_id`` (if needed) and upload ``folder``; the commit URL. HubError on any failure."""
    try:
        from huggingface_hub import HfApi

        api = HfApi()
        api.create_repo(repo_id, private=private, exist_ok=True)
        info = api.upload_folder(folder_path=folder, repo_id=repo_id, commit_message="cliport-push")
    except Exception as e:  # network, token, permissions: all reported as one line
        raise HubError(f"could not push to the Hugging Face Hub repo {repo_id}: {one_line(e)}") from None
    return str(getattr(info, "commit_url", info))


def summary(folder: str) -> str:
    """One JSON line listing the files of a built folder."""
    files = sorted(os.path.relpath(os.path.join(d, f), folder) for d, _, fs in os.walk(folder) for f in fs)
    return json.dumps({"folder": folder, "files": files})


__all__ = [
    "HF_PREFIX",
    "HubError",
    "build_hub_folder",
    "hub_eval_dir",
    "model_card",
    "parse_hub_ref",
    "resolve_run_dir",
    "upload",
]
