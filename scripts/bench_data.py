"""Benchmark the data pipeline; prints one JSON object.

- demos per minute with 1 and 2 workers for two tasks (fresh temp folders),
- bytes per step on disk against the reference's ~6.45 MB of raw camera images per step,
- training samples per second from the DataLoader (augmentation on, 2 workers, batch 8).

Usage: python scripts/bench_data.py [--tasks place-red-in-green block-insertion] [--n 6]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

from cliport.data.generate import DemoConfig, generate
from cliport.utils.machine import measurement_environment

REFERENCE_BYTES_PER_STEP = 6.45e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["place-red-in-green", "block-insertion"])
    parser.add_argument("--n", type=int, default=6, help="episodes per task and worker setting")
    parser.add_argument("--camera-scale", type=float, default=1.0)
    parser.add_argument("--loader-seconds", type=float, default=20.0)
    args = parser.parse_args()
    out: dict = {"cpu_count": os.cpu_count(), "camera_scale": args.camera_scale, "generation": {}}
    with tempfile.TemporaryDirectory() as root:
        for task in args.tasks:
            rates = {}
            for workers in (1, 2):
                config = DemoConfig.defaults(
                    data_dir=os.path.join(root, f"w{workers}"), workers=workers, camera_scale=args.camera_scale
                )
                summary = generate(task, "train", args.n, config, progress=False)
                rates[workers] = summary
            out["generation"][task] = {
                "demos_per_minute_1_worker": rates[1]["demos_per_minute"],
                "demos_per_minute_2_workers": rates[2]["demos_per_minute"],
                "speedup_2_workers": round(rates[2]["demos_per_minute"] / rates[1]["demos_per_minute"], 2),
                "mb_per_step": rates[1]["mb_per_step"],
                "times_smaller_than_raw_images": round(REFERENCE_BYTES_PER_STEP / (rates[1]["mb_per_step"] * 1e6), 1),
            }
        # torch is imported only here: spawned demo workers re-import this script and should not pay for it.
        import torch
        from torch.utils.data import DataLoader

        from cliport.data.dataset import DemoDataset

        dataset = DemoDataset(os.path.join(root, "w1"), args.tasks[0], n_demos=args.n, augment=True)
        torch.manual_seed(0)
        loader = DataLoader(dataset, batch_size=8, shuffle=True, num_workers=2, persistent_workers=True)
        n, start = 0, None
        while start is None or time.perf_counter() - start < args.loader_seconds:
            for batch in loader:
                if start is None:  # skip worker start-up
                    start = time.perf_counter()
                    continue
                n += len(batch["lang"])
        out["loader"] = {
            "samples_per_second": round(n / (time.perf_counter() - start), 1),
            "batch_size": 8,
            "num_workers": 2,
            "augment": True,
        }
    out["environment"] = measurement_environment()
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
