"""Run one episode of a task with any policy (the scripted oracle for demos, an agent for evaluation)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from cliport.env.environment import Environment

Policy = Callable[[dict[str, Any], dict[str, Any]], "dict[str, Any] | None"]


@dataclass
class Episode:
    """What happened in one episode. ``steps`` holds, per action, the observation it was chosen
    from, the action, the reward it earned and the instruction in force (when recorded)."""

    task: str
    seed: int
    total_reward: float = 0.0
    steps: list[dict[str, Any]] = field(default_factory=list)
    n_actions: int = 0
    done: bool = False
    seconds: float = 0.0
    final_observation: dict[str, Any] | None = None

    @property
    def success(self) -> bool:
        return self.total_reward > 0.99


def oracle_policy(env: Environment) -> Policy:
    """The task's scripted expert as a policy."""

    def act(obs: dict[str, Any], info: dict[str, Any]) -> dict[str, Any] | None:
        return _task_of(env).oracle_act(obs)

    return act


#: Mixed with the episode seed to seed a blind expert's guesses (apart from the task's own generator).
BLIND_SEED = 20211108


def blind_policy(env: Environment, seed: int) -> Policy:
    """The language-blind expert of :meth:`Task.blind_plan` as a policy, its guesses seeded by ``seed``.

    At each action it works on the first step of its plan, from where it is, that it has not met yet, with
    the oracle's action for that step (a later step where the oracle finds none); once it has met its whole
    plan it rests (:meth:`Task.rest_action`), so that the goal steps it has met are banked, one per action.
    Once nothing is left to do and the current goal step is not met, no later action could bank anything, and
    it ends the episode (returns None). Where the task has no blind plan (the instruction does not change what
    must be done) it is the oracle.
    """
    task = _task_of(env)
    plan: list[Any] | None = None
    planned = False
    position = 0

    def act(obs: dict[str, Any], info: dict[str, Any]) -> dict[str, Any] | None:
        nonlocal plan, planned, position
        if not planned:
            plan, planned = task.blind_plan(np.random.default_rng([BLIND_SEED, seed])), True
        if plan is None:
            return task.oracle_act(obs)
        while position < len(plan) and task.step_met(plan[position]):
            position += 1
        for step in plan[position:]:
            if not task.step_met(step):
                action = task.pursue(step)
                if action is not None:
                    return action
        return task.rest_action() if task.goals and task.step_met(task.goals[0]) else None

    return act


def scripted_policy(env: Environment, name: str, seed: int) -> Policy:
    """The scripted expert named ``name``: "oracle" (:func:`oracle_policy`) or "blind" (:func:`blind_policy`)."""
    if name == "oracle":
        return oracle_policy(env)
    if name == "blind":
        return blind_policy(env, seed)
    raise ValueError(f"unknown scripted expert {name!r}: 'oracle' or 'blind'")


@runtime_checkable
class ExpertTask(Protocol):
    """What demonstrations need of a task beyond the environment's :class:`~cliport.env.environment.Task`: its
    scripted expert, for ``variants`` the scene's other instructions, and the language-blind expert's parts
    (``cliport.tasks.base.Task`` has them all)."""

    def oracle_act(self, obs: dict[str, Any] | None = None) -> dict[str, Any] | None: ...

    def instruction_variants(self, obs: dict[str, Any] | None = None) -> list[tuple[str, dict[str, Any]]]: ...

    def blind_plan(self, rng: np.random.Generator) -> list[Any] | None: ...

    def step_met(self, step: Any) -> bool: ...

    def pursue(self, step: Any) -> dict[str, Any] | None: ...

    def rest_action(self) -> dict[str, Any]: ...

    @property
    def goals(self) -> list[Any]: ...


def _task_of(env: Environment) -> ExpertTask:
    if not isinstance(env.task, ExpertTask):
        raise ValueError("the environment has no task with an oracle; call env.set_task(task) first")
    return env.task


def run_episode(env: Environment, seed: int, policy: Policy, record: bool = False, variants: bool = False) -> Episode:
    """Reset ``env`` (its task already set) with ``seed`` and act until done or max steps. With ``record`` and
    ``variants`` each recorded step also holds ``variants``: the task's other instructions of that state with
    the oracle's action for each (:meth:`Task.instruction_variants`)."""
    task = env.task
    if task is None:
        raise ValueError("the environment has no task; call env.set_task(task) first")
    start = time.perf_counter()
    obs = env.reset(seed)
    info: dict[str, Any] = {"lang_goal": env.lang_goal}
    episode = Episode(task=getattr(task, "name", type(task).__name__), seed=seed)
    for _ in range(task.max_steps):
        action = policy(obs, info)
        if action is None:
            break
        lang_goal = info.get("lang_goal")
        others = _task_of(env).instruction_variants(obs) if record and variants else None
        next_obs, reward, done, info = env.step(action)
        if record:
            episode.steps.append({"obs": obs, "action": action, "reward": reward, "lang_goal": lang_goal})
            if others is not None:
                episode.steps[-1]["variants"] = others
        episode.total_reward += reward
        episode.n_actions += 1
        obs = next_obs
        if done:
            episode.done = True
            break
    if record:
        episode.final_observation = obs
    episode.seconds = time.perf_counter() - start
    return episode
