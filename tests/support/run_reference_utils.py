"""Run functions of the reference CLIPort's ``cliport/utils/utils.py`` on arrays from a file (test oracle).

    python tests/support/run_reference_utils.py REFERENCE_DIR IN.npz OUT.npz

Both the project and the reference are packages named ``cliport``, so the reference runs in its own
process: this script puts ``REFERENCE_DIR/stubs`` and ``REFERENCE_DIR`` first on ``sys.path`` (see
``REFERENCE_DIR/README.md``), checks that the ``cliport`` it imported is the reference's, and calls
the reference's functions on the inputs. Nothing of the reference is copied into the project.

``IN.npz`` holds ``job`` (a string) and the job's arrays; ``OUT.npz`` receives the results:

- ``fuse``: ``color`` (N, H, W, 3) uint8, ``depth`` (N, H, W), ``configs`` (JSON: one camera dict per
  view with ``intrinsics``, ``position``, ``rotation``), ``bounds`` (3, 2), ``pixel_size`` ->
  ``cmap``/``hmap`` of ``get_fused_heightmap``, the per-camera ``heightmaps``/``colormaps`` of
  ``reconstruct_heightmaps``, and ``points`` (N, H, W, 3): ``get_pointcloud`` + ``transform_pointcloud``.
- ``pixels``: ``pix`` (K, 2) int, ``height`` (rows, cols), ``xyz`` (K, 3), ``bounds``, ``pixel_size`` ->
  ``pix_to_xyz`` of every ``pix`` (K, 3) and ``xyz_to_pix`` of every ``xyz`` (K, 2).
- ``rotations``: ``euler`` (K, 3), ``quat`` (K, 4) -> ``eulerXYZ_to_quatXYZW`` of each (K, 4),
  ``quatXYZW_to_eulerXYZ`` of each (K, 3) and ``act_quat`` (K, 4): the reference agent's
  ``eulerXYZ_to_quatXYZW((0, 0, -theta))`` for ``theta`` (K,).
- ``perturb``: ``img`` (H, W, 6) float32, ``pixels`` (2, 2) int (row, col), ``seeds`` (K,) -> for each seed, the
  reference's ``perturb(img, pixels)`` (its SE(2) training augmentation) after ``np.random.seed(seed)``: ``image``
  (K, H, W, 6), ``rounded`` (K, 2, 2) pixel labels, and its draws ``theta`` (K,), ``trans`` (K, 2), ``pivot`` (K, 2).
- ``cameras``: the reference's ``RealSenseD415.CONFIG`` and ``Oracle.CONFIG`` as JSON (``configs``).
"""

from __future__ import annotations

import contextlib
import json
import os
import sys


def _import_reference(reference_dir: str):
    for path in (os.path.join(reference_dir, "stubs"), reference_dir):
        sys.path.insert(0, path)
    with contextlib.redirect_stdout(sys.stderr):
        import cliport
        from cliport.tasks import cameras
        from cliport.utils import utils
    expected = os.path.realpath(os.path.join(reference_dir, "cliport"))
    if os.path.realpath(os.path.dirname(cliport.__file__)) != expected:
        raise SystemExit(f"imported another package named cliport ({cliport.__file__}), not {expected}")
    return utils, cameras


def _camera_json(configs: list[dict]) -> str:
    return json.dumps([{k: list(v) if isinstance(v, tuple) else v for k, v in c.items()} for c in configs])


def main(reference_dir: str, src: str, dst: str) -> None:
    utils, cameras = _import_reference(reference_dir)
    import numpy as np

    inp = dict(np.load(src, allow_pickle=False))
    job = str(inp.pop("job"))
    out: dict[str, np.ndarray] = {}
    if job == "fuse":
        configs = json.loads(str(inp["configs"]))
        obs = {"color": tuple(inp["color"]), "depth": tuple(inp["depth"])}
        bounds, pixel_size = inp["bounds"], float(inp["pixel_size"])
        out["cmap"], out["hmap"] = utils.get_fused_heightmap(obs, configs, bounds, pixel_size)
        heightmaps, colormaps = utils.reconstruct_heightmaps(obs["color"], obs["depth"], configs, bounds, pixel_size)
        out["heightmaps"], out["colormaps"] = np.stack(heightmaps), np.stack(colormaps)
        points = []
        for depth, config in zip(obs["depth"], configs, strict=True):
            xyz = utils.get_pointcloud(depth, np.array(config["intrinsics"]).reshape(3, 3))
            rotation = np.array(utils.p.getMatrixFromQuaternion(config["rotation"])).reshape(3, 3)
            transform = np.eye(4)
            transform[:3, :] = np.hstack((rotation, np.array(config["position"]).reshape(3, 1)))
            points.append(utils.transform_pointcloud(xyz, transform))
        out["points"] = np.stack(points)
    elif job == "pixels":
        bounds, pixel_size = inp["bounds"], float(inp["pixel_size"])
        out["xyz"] = np.array([utils.pix_to_xyz(tuple(p), inp["height"], bounds, pixel_size) for p in inp["pix"]])
        out["pix"] = np.array([utils.xyz_to_pix(x, bounds, pixel_size) for x in inp["xyz"]])
    elif job == "rotations":
        out["quat"] = np.array([utils.eulerXYZ_to_quatXYZW(tuple(e)) for e in inp["euler"]])
        out["euler"] = np.array([utils.quatXYZW_to_eulerXYZ(tuple(q)) for q in inp["quat"]])
        out["act_quat"] = np.array([utils.eulerXYZ_to_quatXYZW((0, 0, -theta)) for theta in inp["theta"]])
    elif job == "perturb":
        runs = []
        for seed in inp["seeds"]:
            np.random.seed(int(seed))
            pixels = [tuple(int(v) for v in p) for p in inp["pixels"]]
            image, _, rounded, (theta, trans, pivot) = utils.perturb(inp["img"], pixels)
            runs.append((image, np.array(rounded), theta, np.asarray(trans), np.asarray(pivot, dtype=np.float64)))
        for i, key in enumerate(("image", "rounded", "theta", "trans", "pivot")):
            out[key] = np.stack([np.asarray(r[i]) for r in runs])
    elif job == "cameras":
        out["configs"] = np.array(
            json.dumps(
                {
                    "realsense": json.loads(_camera_json(cameras.RealSenseD415.CONFIG)),
                    "oracle": json.loads(_camera_json(cameras.Oracle.CONFIG)),
                }
            )
        )
    else:
        raise SystemExit(f"unknown job {job!r}")
    np.savez(dst, **out)


if __name__ == "__main__":
    if len(sys.argv) != 4:
        raise SystemExit(__doc__.strip().splitlines()[2])
    main(*sys.argv[1:])
