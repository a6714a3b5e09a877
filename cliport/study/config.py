"""The study's settings (:class:`StudyConfig`), its cells, the task groups of the papers' tables, and the check
that a study folder is only ever continued with the settings it was started with."""

from __future__ import annotations

import dataclasses
import os
from typing import Any

from cliport.errors import ConfigError
from cliport.evaluation.published import paper_recipes, published_results, published_task_name
from cliport.train.config import TrainConfig
from cliport.train.run_defaults import RunDefaults, run_defaults
from cliport.utils.config import from_dict, read_defaults
from cliport.utils.files import read_json

#: The file in a study folder that records the settings it was started with.
SETTINGS_FILE = "study_config.json"

#: Train settings the study sets itself (so ``train_options`` may not).
_STUDY_TRAIN_KEYS = {
    "agent", "task", "n_demos", "n_steps", "data_dir", "run_dir", "recipe", "seed", "val_episodes", "batch_size",
    "device", "checkpoint_steps", "agent_config", "env", "val_workers",
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Cell:
    """One training run of the study and its evaluation: train, then validate and test every checkpoint."""

    task: str
    agent: str
    recipe: str
    n_demos: int
    seed: int

    def label(self) -> str:
        return f"{self.task} {self.agent} {self.recipe} n{self.n_demos} s{self.seed}"


@dataclasses.dataclass
class StudyConfig:
    """A reproduction study (``cliport-reproduce``).

    Args:
        task: task to study (one task; --tasks for several).
        tasks: tasks to study, each on its own (task names, or a group: transporter-paper, the Transporter
            paper's 10 tasks; cliport-table1, CLIPort's Table 1; or a multi-task group of cliport-tasks).
        agents: registered agent names to train.
        n_demos: demo counts, one run per (agent, count).
        n_steps: training steps of every run.
        out: study folder (runs, evaluations, table, plot).
        data_dir: folder of the demonstrations.
        val_episodes: val episodes per checkpoint (checkpoint selection).
        test_episodes: test episodes per checkpoint.
        batch_size: training batch size (None: configs/train.toml's).
        device: auto, cpu, cuda, ... (None: configs/train.toml's).
        seed: training seed (when seeds is empty).
        seeds: training seeds: one run per (agent, demos, seed), reported as mean and standard deviation
            over seeds (the CLIPort authors advise 3 or more); empty = [seed].
        camera_scale: camera resolution of the demos and of every evaluation episode.
        demo_workers: parallel simulators for demo generation (per demo shard).
        demo_shards: demo generation jobs per task, each generating its share of the demos (cliport-demos
            --shard I/K): with a cluster, the shards run at once.
        recipes: training recipes (configs/recipes.toml), one run per (agent, demos, recipe, seed); empty = each
            agent's papers' recipes (transporter_only: ravens and cliport; the CLIPort agents: cliport), so that
            every published column is compared with a run trained as that paper's code trains.
        agent_config: agent settings (e.g. {"width": 0.25, "clip_weights": "random"}); each run takes the keys
            its agent has, and a key no studied agent has is an error.
        train_options: other cliport-train settings of every run (e.g. {"num_workers": 0, "save_last_every":
            100}); the ones the study sets itself are refused.
        checkpoint_steps: checkpoint steps (None: configs/train.toml's).
        eval_workers: simulator processes for validation and test episodes (None: cell_cpus, at most the
            episodes of one checkpoint).
        threads: torch threads of each cell's training and agent. Fixed, not the machine's core count: the
            thread count changes the last bits of CPU training, and a cell's result must not depend on where
            it ran.
        cell_cpus: CPU cores of each cell: what a cell asks Ray for, and its default simulator count (None: the
            usable cores of this machine, at most 8).
        cluster: none (one cell after another in this process), local (start Ray on this machine and run the
            cells as Ray tasks), auto (join the Ray cluster running on this machine) or the address HOST:PORT of
            a Ray cluster's head (ray start --head).
        retries: times Ray runs a cell (or a demo shard) again when its worker or node dies; each run resumes
            from the cell's last checkpoint.
    """

    agents: list[str]
    n_demos: list[int]
    n_steps: int
    out: str
    data_dir: str
    task: str = ""
    tasks: list[str] = dataclasses.field(default_factory=list)
    val_episodes: int = 100
    test_episodes: int = 100
    batch_size: int | None = None
    device: str | None = None
    seed: int = 0
    seeds: list[int] = dataclasses.field(default_factory=list)
    camera_scale: float = 1.0
    demo_workers: int = 1
    demo_shards: int = 1
    agent_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    train_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    recipes: list[str] = dataclasses.field(default_factory=list)
    checkpoint_steps: list[int] | None = None
    eval_workers: int | None = None
    threads: int = 1
    cell_cpus: int | None = None
    cluster: str = "none"
    retries: int = 3

    def study_tasks(self) -> list[str]:
        """The studied tasks: ``tasks``, or ``[task]``."""
        return list(self.tasks) or ([self.task] if self.task else [])

    def task_dir(self, task: str) -> str:
        """Where a task's runs, results.json, table.md and plot go: the study folder itself when it studies one
        task (as before several could be studied), else its ``TASK`` subfolder."""
        return self.out if len(self.study_tasks()) <= 1 else os.path.join(self.out, task)

    def training_seeds(self) -> list[int]:
        return sorted(set(self.seeds)) or [self.seed]

    def agent_recipes(self, agent: str) -> list[str]:
        """The recipes ``agent`` trains with in this study."""
        return list(self.recipes) or paper_recipes(agent) or [read_defaults("train")["recipe"]]

    def cells(self) -> list[Cell]:
        """Every cell, in the order the serial study runs them and the tables list them."""
        return [
            Cell(task, agent, recipe, n, seed)
            for task in self.study_tasks()
            for agent in self.agents
            for recipe in self.agent_recipes(agent)
            for n in self.n_demos
            for seed in self.training_seeds()
        ]

    def resolved_cell_cpus(self) -> int:
        from cliport.evaluation.engine import MAX_DEFAULT_WORKERS, usable_cores

        return self.cell_cpus or min(usable_cores(), MAX_DEFAULT_WORKERS)

    def eval_worker_count(self, n_episodes: int) -> int:
        """Simulators for ``n_episodes`` episodes of one checkpoint: eval_workers (checked), else cell_cpus."""
        from cliport.evaluation.engine import resolve_workers

        if self.eval_workers is not None:
            return resolve_workers(self.eval_workers, n_episodes, "--eval-workers")
        return max(1, min(self.resolved_cell_cpus(), n_episodes))

    def run_dir(self, cell: Cell) -> str:
        """The cell's run folder: TASK_DIR/runs/AGENT-RECIPE-nN, with -sSEED when the study has several seeds."""
        suffix = f"-s{cell.seed}" if len(self.training_seeds()) > 1 else ""
        name = f"{cell.agent}-{cell.recipe}-n{cell.n_demos}{suffix}"
        return os.path.join(self.task_dir(cell.task), "runs", name)

    def cell_defaults(self, task: str) -> RunDefaults:
        """The place rotations and renderer of the task's cells: the papers' protocol
        (:func:`~cliport.train.run_defaults.run_defaults` with ``papers_protocol``), the agents' 36 place rotations on
        every task, round bowls too, so that each cell compares with the published columns; ``--n-rotations``
        (``agent_config``) changes that."""
        return run_defaults(task, n_rotations=self.agent_config.get("n_rotations"), papers_protocol=True)

    def train_config(
        self,
        agent: str,
        n_demos: int,
        seed: int | None = None,
        recipe: str | None = None,
        task: str | None = None,
    ) -> TrainConfig:
        """The train config of the (task, agent, n_demos, recipe, seed) run (its folder names the recipe, and
        the seed when there are several)."""
        seed = self.seed if seed is None else seed
        recipe = recipe or self.agent_recipes(agent)[0]
        task = task or self.study_tasks()[0]
        from cliport.agents import agent_class

        fields = {f.name for f in dataclasses.fields(agent_class(agent).config_class)}
        studied = {f.name for a in self.agents for f in dataclasses.fields(agent_class(a).config_class)}
        unknown = sorted(set(self.agent_config) - studied)
        if unknown:
            raise ConfigError(f"no studied agent has the setting(s) {', '.join(unknown)}")
        reserved = sorted(set(self.train_options) & _STUDY_TRAIN_KEYS)
        if reserved:
            raise ConfigError(
                f"--train-option cannot set {', '.join(reserved)}: the study sets it (use its own flag if it has one)"
            )
        defaults = self.cell_defaults(task)
        given = {
            **self.train_options,
            "agent": agent,
            "task": task,
            "n_demos": n_demos,
            "n_steps": self.n_steps,
            "data_dir": self.data_dir,
            "run_dir": self.run_dir(Cell(task, agent, recipe, n_demos, seed)),
            "recipe": recipe,
            "seed": seed,
            "val_episodes": self.val_episodes,
            "batch_size": self.batch_size,
            "device": self.device,
            "checkpoint_steps": self.checkpoint_steps,
            "agent_config": {
                **defaults.overrides()["agent_config"],
                **{k: v for k, v in self.agent_config.items() if k in fields},
            },
            "env": {"camera_scale": self.camera_scale, "renderer": defaults.renderer},
        }
        return TrainConfig.build({k: v for k, v in given.items() if v is not None})


# ---------------------------------------------------------------------- task groups
def study_groups() -> dict[str, list[str]]:
    """The papers' tables as task groups, read from the published results: ``transporter-paper`` (the
    Transporter Networks paper's 10 tasks) and ``cliport-table1`` (the tasks of CLIPort's Table 1)."""
    from cliport import tasks

    data = published_results()
    ours = {published_task_name(name): name for name in tasks.names()}  # the table's name -> ours
    return {
        "transporter-paper": list(data["transporter_paper_test"]),
        "cliport-table1": [ours[name] for name in data["cliport_table1_test"]],
    }


def expand_tasks(names: list[str]) -> list[str]:
    """Task names with each group (a table of :func:`study_groups`, or a multi-task group) replaced by its tasks,
    each once, in order; an unknown name is an UnknownNameError."""
    from cliport import tasks

    groups = study_groups()
    out: list[str] = []
    for name in names:
        members = groups.get(name) or tasks.resolve(name)
        out += [m for m in members if m not in out]
    return out


# ---------------------------------------------------------------------- the settings a folder keeps
#: The settings that decide what a study's cells compute; a folder is only continued with the same ones.
SETTINGS = (
    "tasks", "agents", "n_demos", "n_steps", "seeds", "recipes", "val_episodes", "test_episodes", "batch_size",
    "camera_scale", "agent_config", "train_options", "checkpoint_steps", "threads", "demo_shards",
)  # fmt: skip


def settings(config: StudyConfig) -> dict[str, Any]:
    """The values of :data:`SETTINGS` of ``config``, resolved (the tasks, seeds and recipes it runs)."""
    values = dataclasses.asdict(config)
    values["tasks"] = config.study_tasks()
    values["seeds"] = config.training_seeds()
    values["recipes"] = {agent: config.agent_recipes(agent) for agent in config.agents}
    return {key: values[key] for key in SETTINGS}


def saved_config(out: str) -> StudyConfig:
    """The StudyConfig a study folder was started with (UserError if it holds no study)."""
    path = os.path.join(out, SETTINGS_FILE)
    if not os.path.isfile(path):
        raise ConfigError(f"{out} holds no study (no {SETTINGS_FILE})")
    data = read_json(path)
    known = {f.name for f in dataclasses.fields(StudyConfig)}
    config = from_dict(StudyConfig, {k: v for k, v in data.items() if k in known}, path)
    config.out = out
    return config


def check_settings(config: StudyConfig) -> None:
    """Refuse (ConfigError, one line) to continue a study folder started with other settings. A folder saved
    before a setting existed is compared on the settings it records."""
    path = os.path.join(config.out, SETTINGS_FILE)
    if not os.path.isfile(path):
        return
    saved_data = read_json(path)
    saved = settings(saved_config(config.out))
    ours = settings(config)
    differ = [key for key in SETTINGS if (key in saved_data or key in ("tasks", "recipes")) and saved[key] != ours[key]]
    if differ:
        shown = "; ".join(f"{key} {_short(saved[key])} there, {_short(ours[key])} here" for key in differ)
        raise ConfigError(
            f"{config.out} holds a study with other settings ({shown}): pass the same settings to continue it, "
            "or another --out"
        )


def _short(value: Any) -> str:
    text = str(value)
    return text if len(text) <= 60 else text[:57] + "..."
