"""Pictures and videos of episodes: heatmaps over the observation, GIF/MP4 writing."""

from __future__ import annotations

import math
import os

import cv2
import numpy as np


def heatmap_overlay(color: np.ndarray, heatmap: np.ndarray, alpha: float = 0.55) -> np.ndarray:
    """(H, W, 3) uint8 observation blended with a (H, W) heatmap (normalised to its max, jet colours)."""
    norm = heatmap / max(float(heatmap.max()), 1e-12)
    colored = cv2.applyColorMap((np.clip(norm, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_JET)[..., ::-1]
    blend = (1 - alpha) * color.astype(np.float32) + alpha * colored.astype(np.float32)
    return np.clip(blend, 0, 255).astype(np.uint8)


def fill_empty_cells(color: np.ndarray) -> np.ndarray:
    """A copy of a fused (H, W, 3) colour map whose empty cells (no camera saw them: all zero) are filled
    from their neighbours, for pictures only: agents always see the map as fused."""
    empty = np.all(color == 0, axis=-1)
    if not empty.any() or empty.all():
        return color
    return cv2.inpaint(np.ascontiguousarray(color), empty.astype(np.uint8), 2, cv2.INPAINT_TELEA)


def action_panel(
    obs: dict, act: dict, instruction: str | None, scale: int = 2, similarity: dict[str, np.ndarray] | None = None
) -> np.ndarray:
    """Observation | pick heatmap with the pick pixel | place heatmap with the place pixel and its yaw,
    side by side (each 320 x 160 scaled by ``scale``), with the instruction written above; then one panel per
    ``similarity`` map (``{text: (H, W)}``, an agent's ``similarity_heatmaps``), spread from its minimum to its
    maximum and labelled with its text. Empty cells of the fused map are filled for display
    (:func:`fill_empty_cells`)."""
    color = fill_empty_cells(obs["color"])
    pick = heatmap_overlay(color, act["pick_heatmap"])
    place = heatmap_overlay(color, act["place_heatmap"])
    shown = [color, pick, place]
    for values in (similarity or {}).values():
        spread = (values - values.min()) / max(float(values.max() - values.min()), 1e-12)
        shown.append(heatmap_overlay(color, spread))
    panels = [cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST) for img in shown]
    for panel, text in zip(panels[3:], similarity or {}, strict=True):
        cv2.putText(panel, f"~ {text}"[:40], (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    pu, pv = act["pick_pix"]
    qu, qv = act["place_pix"]
    cv2.circle(panels[1], (int(pv * scale), int(pu * scale)), 6, (255, 255, 255), 2)
    centre = (int(qv * scale), int(qu * scale))
    cv2.circle(panels[2], centre, 6, (255, 255, 255), 2)
    # The yaw arrow in image axes: columns run along +x and rows along +y.
    theta = float(act["place_rot"])
    tip = (int(centre[0] + 18 * math.cos(theta)), int(centre[1] + 18 * math.sin(theta)))
    cv2.arrowedLine(panels[2], centre, tip, (255, 255, 255), 2, tipLength=0.3)
    image = np.concatenate(panels, axis=1)
    banner = np.full((28, image.shape[1], 3), 255, np.uint8)
    cv2.putText(banner, (instruction or "")[:90], (6, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([banner, image], axis=0)


def save_png(path: str, rgb: np.ndarray) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if not cv2.imwrite(path, rgb[..., ::-1]):
        raise OSError(f"could not write image {path}")


def save_video(path: str, frames: list[np.ndarray], fps: int = 20) -> None:
    """Write RGB frames as a GIF (``.gif``) or MP4 (``.mp4``)."""
    if not frames:
        raise ValueError("no frames to write")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if path.endswith(".gif"):
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    elif path.endswith(".mp4"):
        h, w = frames[0].shape[:2]
        writer = cv2.VideoWriter(path, cv2.VideoWriter.fourcc(*"mp4v"), fps, (w, h))
        for f in frames:
            writer.write(f[..., ::-1])
        writer.release()
    else:
        raise ValueError(f"video path must end in .gif or .mp4, got {path!r}")
