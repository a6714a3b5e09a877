"""Image-level check of the place rotation convention with feature-free (height pass-through) nets.

A world yaw theta is counter-clockwise about +z; rows run along +y and columns along +x. An L shape is
drawn at the pick pixel and a copy rotated by theta at the place pixel (taller, so that it out-scores
the original); decoding the best rotation bin must give theta.
"""

import math

import numpy as np
import pytest
import torch
from torch import nn

from cliport.agents import make_agent
from cliport.env.transforms import quat_to_yaw
from cliport.models.heads import PlaceHead

H, W, CROP, N_ROT = 96, 64, 32, 12
PICK = (30, 20)
PLACE = (64, 40)


class HeightPassThrough(nn.Module):
    """Returns the raw height channel as a 1-channel feature map."""

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        return x[:, 3:4]


class PeakAt(nn.Module):
    """Pick logits with a single peak at a fixed pixel of the (padded) pick-net input."""

    def __init__(self, pix: tuple[int, int]) -> None:
        super().__init__()
        self.pix = pix
        self.dummy = nn.Parameter(torch.zeros(()))

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        out = torch.zeros(x.shape[0], 1, *x.shape[-2:]) + self.dummy
        out[:, :, self.pix[0], self.pix[1]] = 10.0
        return out


def _draw_l_shape(height: np.ndarray, centre: tuple[int, int], yaw: float, value: float) -> None:
    """An L: a 12 x 3 px bar along +x and a 3 x 7 px bar along +y at its +x end, rotated by `yaw`."""
    xs, ys = np.meshgrid(np.arange(-6.0, 6.01, 0.25), np.arange(-1.5, 1.51, 0.25))
    long_bar = np.stack([xs.ravel(), ys.ravel()], 1)
    xs, ys = np.meshgrid(np.arange(3.0, 6.01, 0.25), np.arange(1.5, 7.01, 0.25))
    short_bar = np.stack([xs.ravel(), ys.ravel()], 1)
    pts = np.concatenate([long_bar, short_bar])
    c, s = math.cos(yaw), math.sin(yaw)
    dx = c * pts[:, 0] - s * pts[:, 1]
    dy = s * pts[:, 0] + c * pts[:, 1]
    u = np.round(centre[0] + dy).astype(int)
    v = np.round(centre[1] + dx).astype(int)
    height[u, v] = value


def _scene(theta: float) -> tuple[np.ndarray, np.ndarray]:
    height = np.zeros((H, W), np.float32)
    _draw_l_shape(height, PICK, 0.0, 0.01)
    _draw_l_shape(height, PLACE, theta, 0.02)
    color = np.zeros((H, W, 3), np.uint8)
    return color, height


def _angle_error(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


@pytest.mark.parametrize("theta_deg", [0, 60, 150, 270])
def test_place_head_decodes_world_yaw(theta_deg: int) -> None:
    theta = math.radians(theta_deg)
    color, height = _scene(theta)
    x = torch.cat([torch.zeros(1, 3, H, W), torch.from_numpy(height)[None, None].expand(1, 3, H, W)], 1)
    head = PlaceHead(HeightPassThrough(), HeightPassThrough(), CROP, N_ROT)
    logits = head(x, torch.tensor([PICK]))[0]
    k, u, v = np.unravel_index(int(torch.argmax(logits)), logits.shape)
    assert abs(u - PLACE[0]) <= 1 and abs(v - PLACE[1]) <= 1
    assert _angle_error(head.bin_yaw(int(k)), theta) <= 2 * math.pi / N_ROT / 2 + 1e-6


def test_mirrored_convention_would_fail() -> None:
    # Guards the test itself: with theta = 90 deg the clockwise reading (-90 deg) must not be decoded.
    theta = math.radians(90)
    _, height = _scene(theta)
    x = torch.cat([torch.zeros(1, 3, H, W), torch.from_numpy(height)[None, None].expand(1, 3, H, W)], 1)
    head = PlaceHead(HeightPassThrough(), HeightPassThrough(), CROP, N_ROT)
    k = int(torch.argmax(head(x, torch.tensor([PICK]))[0])) // (H * W)
    assert _angle_error(head.bin_yaw(k), -theta) > math.radians(90)
    # Bin k is the image rotated counter-clockwise on screen by k steps, i.e. world yaw -k steps.
    assert k == round(-theta / (2 * math.pi / N_ROT)) % N_ROT


@pytest.mark.parametrize("theta_deg", [60, 270])
def test_agent_pose1_yaw_equals_world_rotation(theta_deg: int) -> None:
    theta = math.radians(theta_deg)
    color, height = _scene(theta)
    agent = make_agent("transporter_only", {"width": 0.125, "crop_size": CROP, "n_rotations": N_ROT})
    left = (H - W) // 2  # the pick head pads the columns to a square
    agent.pick.net = PeakAt((PICK[0], PICK[1] + left))
    agent.place.key_net = HeightPassThrough()
    agent.place.query_net = HeightPassThrough()
    out = agent.act({"color": color, "height": height}, None)
    assert out["pick_pix"] == PICK
    assert abs(out["place_pix"][0] - PLACE[0]) <= 1 and abs(out["place_pix"][1] - PLACE[1]) <= 1
    assert _angle_error(quat_to_yaw(out["pose1"][1]), theta) <= 2 * math.pi / N_ROT / 2 + 1e-6
    assert _angle_error(out["place_rot"], theta) <= 2 * math.pi / N_ROT / 2 + 1e-6
    assert abs(quat_to_yaw(out["pose0"][1])) < 1e-9
