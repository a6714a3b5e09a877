"""The study's cells as Ray tasks (``--cluster local|auto|HOST:PORT``). Ray is an optional extra, imported here
only: ``pip install -e ".[cluster]"``.

Each task's demo shards are Ray tasks; each cell is a Ray task that depends on its task's shards, asks for
``cell_cpus`` CPUs and, where the cluster has GPUs, one GPU, and runs in a fresh worker process (``max_calls=1``:
no state of one cell, CUDA's included, is left for the next). A worker or node that dies makes Ray run the cell
again (``retries`` times), and the new run resumes from the cell's last checkpoint (:mod:`cliport.study.cells`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
import traceback
from collections.abc import Callable, Iterator
from typing import Any

from cliport.errors import ConfigError
from cliport.study.cells import CellFiles, generate_demos, run_cell
from cliport.study.config import Cell, StudyConfig

#: Seconds to wait for a cluster's head to answer before saying it does not.
CONNECT_TIMEOUT = 5.0
#: Object store of a local Ray: the study only passes small records between processes.
_LOCAL_OBJECT_STORE = 256 * 1024**2


def _import_ray(cluster: str) -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(f'--cluster {cluster} needs Ray: pip install -e ".[cluster]" (or pip install ray)') from None
    return ray


def _check_reachable(address: str) -> None:
    """ConfigError, quickly, unless something listens at ``address`` (HOST:PORT)."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"--cluster must be none, local, auto or a Ray head's HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT).close()
    except OSError as e:
        why = e.strerror or type(e).__name__
        raise ConfigError(
            f"no Ray cluster answers at {address} ({why}): start one there with `ray start --head`, "
            "or use --cluster local"
        ) from None


def check_cluster(cluster: str) -> None:
    """ConfigError, before any work starts, unless ``--cluster`` can be used: none; local or auto with Ray
    installed; an address with Ray installed and something listening there."""
    if cluster == "none":
        return
    _import_ray(cluster)
    if cluster not in ("local", "auto"):
        _check_reachable(cluster)


@contextlib.contextmanager
def connected(cluster: str, num_cpus: int) -> Iterator[Any]:
    """Ray, started here (``local``, with ``num_cpus`` CPUs) or joined (``auto``, an address); shut down (or
    left) at the end. A Ray already initialised in this process is used as it is."""
    ray = _import_ray(cluster)
    if ray.is_initialized():
        yield ray
        return
    quiet = {"logging_level": logging.ERROR, "log_to_driver": False}
    if cluster == "local":
        ray.init(num_cpus=num_cpus, include_dashboard=False, object_store_memory=_LOCAL_OBJECT_STORE, **quiet)
    else:
        if cluster != "auto":
            _check_reachable(cluster)
        try:
            ray.init(address=cluster, **quiet)
        except (ConnectionError, RuntimeError, ValueError) as e:
            first = (str(e).strip().splitlines() or [type(e).__name__])[0]
            hint = (
                ""
                if cluster == "auto"
                else " (a cluster with token authentication also needs RAY_AUTH_MODE=token here)"
            )
            raise ConfigError(f"cannot join the Ray cluster at {cluster}: {first}{hint}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _largest_node_cpus(ray: Any) -> float:
    return max((n["Resources"].get("CPU", 0.0) for n in ray.nodes() if n.get("Alive")), default=0.0)


def _cell_task(config: StudyConfig, cell: Cell, *demos: Any) -> dict[str, Any]:
    """A cell in a Ray worker: its output goes to the cell's log.txt (tracebacks too)."""
    files = CellFiles(config, cell)
    os.makedirs(files.folder, exist_ok=True)
    with open(files.log, "a") as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        logging.basicConfig(level=logging.INFO, format="%(message)s", stream=log, force=True)
        try:
            return run_cell(config, cell, progress=False)
        except BaseException:
            traceback.print_exc(file=log)
            raise


def _demo_task(config: StudyConfig, task: str, shard: int) -> dict[str, Any]:
    return generate_demos(config, task, shard, progress=False)


def gpus_per_cell(ray: Any, config: StudyConfig) -> int:
    """The GPUs each cell asks for on the connected cluster (1 where it has GPUs, unless --device cpu); a
    ConfigError where the cluster cannot run the study's cells (no GPU for --device cuda, too few CPUs)."""
    gpus = ray.cluster_resources().get("GPU", 0.0)
    device = config.device or "auto"
    if device.startswith("cuda") and gpus < 1:
        raise ConfigError(f"--device {device} but the Ray cluster has no GPUs")
    largest = _largest_node_cpus(ray)
    for flag, value in (("--cell-cpus", config.resolved_cell_cpus()), ("--demo-workers", config.demo_workers)):
        if value > largest:
            raise ConfigError(f"{flag} {value} is more than the {largest:g} CPUs of the cluster's largest node")
    return 1 if gpus >= 1 and device != "cpu" else 0


def run_cells(
    ray: Any,
    config: StudyConfig,
    cells: list[Cell],
    demo_tasks: list[str],
    finished: Callable[[Cell, dict[str, Any]], None],
) -> list[tuple[Cell, str]]:
    """Run ``cells`` (none finished yet) as Ray tasks on the connected ``ray`` (:func:`connected`), after the
    demos of ``demo_tasks``; ``finished(cell, record)`` hears of each completion as it comes. Returns the failed
    cells with their error line."""
    demo_remote = ray.remote(max_calls=1)(_demo_task).options(num_cpus=config.demo_workers, max_retries=config.retries)
    cell_remote = ray.remote(max_calls=1)(_cell_task).options(
        num_cpus=config.resolved_cell_cpus(), num_gpus=gpus_per_cell(ray, config), max_retries=config.retries
    )
    demos = {task: [demo_remote.remote(config, task, i) for i in range(config.demo_shards)] for task in demo_tasks}
    pending = {cell_remote.remote(config, cell, *demos[cell.task]): cell for cell in cells}
    failed: list[tuple[Cell, str]] = []
    while pending:
        # Bounded: a Ctrl-C is seen within a second.
        ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
        for ref in ready:
            cell = pending.pop(ref)
            try:
                record = ray.get(ref)
            except Exception as e:  # the cell's own error, or Ray's when its worker died too often
                failed.append((cell, _error_line(e, CellFiles(config, cell).log)))
                print(f"cell failed: {cell.label()}: {failed[-1][1]}", file=sys.stderr, flush=True)
                continue
            finished(cell, record)
    return failed


def _error_line(error: BaseException, log: str) -> str:
    cause = getattr(error, "cause", None) or error  # a RayTaskError wraps the task's exception
    first = (str(cause).strip().splitlines() or [type(cause).__name__])[0]
    # A failed argument (its task's demo shard) fails the cell before it starts, with that error as its cause.
    where = "while generating its task's demos" if "could not be computed" in str(error) else f"log: {log}"
    return f"{type(cause).__name__}: {first} ({where})"
