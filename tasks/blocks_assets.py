"""Procedural assets of the blocks family: L block and slotted fixture, pyramid base, Hanoi stand and
rings, box-corner marker. Each builder returns ``compound`` parts (body frame, metres)."""

from __future__ import annotations

import math

from cliport.env import shapes
from cliport.env.shapes import Color

BLOCK = (0.04, 0.04, 0.04)
BOWL = (0.12, 0.12, 0.0)
BOWL_TOLERANCE = 0.05  # the reference's pos_eps for a block in a bowl
BROWN_SHADES: tuple[Color, Color, Color] = ((196, 160, 132), (156, 117, 95), (104, 72, 54))  # light, mid, dark

# L block: two 4 cm arms inside a 10 x 10 cm square centred on the body origin, 4 cm tall.
ELL_SIZE = 0.10
ELL_ARM = 0.04
ELL_HEIGHT = 0.04
SLOT_CLEARANCE = 0.004  # per side; an L in an L slot can then sit at most 5.7 mm from the target
FIXTURE_WALL = 0.02
FIXTURE_HEIGHT = 0.02


def ell_polygon() -> list[tuple[float, float]]:
    """Outline of the L block (counter-clockwise): a vertical arm at -x and a horizontal arm at -y."""
    h, inner = ELL_SIZE / 2, -ELL_SIZE / 2 + ELL_ARM
    return [(-h, -h), (h, -h), (h, inner), (inner, inner), (inner, h), (-h, h)]


def fixture_parts() -> list[dict]:
    """A square frame with an L-shaped through-slot (the L block grown by ``SLOT_CLEARANCE``).

    Built from the solid cells of a 4 x 4 grid whose lines are the slot's edges, so the slot is
    exactly concave (no convex hull fills it).
    """
    h, inner, c = ELL_SIZE / 2, -ELL_SIZE / 2 + ELL_ARM, SLOT_CLEARANCE
    outer = h + c + FIXTURE_WALL
    lines = [-outer, -h - c, inner + c, h + c, outer]
    parts = []
    for i in range(4):
        for j in range(4):
            in_slot = (i, j) in {(1, 1), (1, 2), (2, 1)}  # cells (x index, y index) of the L slot
            if in_slot:
                continue
            x0, x1, y0, y1 = lines[i], lines[i + 1], lines[j], lines[j + 1]
            parts.append(
                {
                    "type": "box",
                    "size": (x1 - x0, y1 - y0, FIXTURE_HEIGHT),
                    "position": ((x0 + x1) / 2, (y0 + y1) / 2, FIXTURE_HEIGHT / 2),
                }
            )
    return parts


FIXTURE_SIZE = (2 * (ELL_SIZE / 2 + SLOT_CLEARANCE + FIXTURE_WALL),) * 2 + (FIXTURE_HEIGHT,)

# Pyramid base: three 5 cm tiles along y.
TILE = (0.05, 0.05, 0.005)
PYRAMID_BASE_SIZE = (0.05, 0.15, 0.005)


def pyramid_base_parts(colors: tuple[Color, Color, Color]) -> list[dict]:
    """Three tiles at y = -5, 0, +5 cm, coloured ``colors`` in that order."""
    return [
        {"type": "box", "size": TILE, "position": (0.0, y, TILE[2] / 2), "color": color}
        for y, color in zip((-0.05, 0.0, 0.05), colors, strict=True)
    ]


def pyramid_targets() -> list[tuple[float, float, float]]:
    """Block centres in the base frame: bottom row (3), middle row (2), top (1)."""
    z0 = TILE[2] + BLOCK[2] / 2
    return [
        (0.0, -0.05, z0),
        (0.0, 0.0, z0),
        (0.0, 0.05, z0),
        (0.0, -0.025, z0 + BLOCK[2]),
        (0.0, 0.025, z0 + BLOCK[2]),
        (0.0, 0.0, z0 + 2 * BLOCK[2]),
    ]


# Towers of Hanoi: a 12 x 36 cm stand, rods 12 cm apart; rings 10 mm tall, inner radius 15 mm.
STAND_SIZE = (0.12, 0.36, 0.01)
ROD_Y = (-0.12, 0.0, 0.12)
ROD_RADIUS = 0.008
ROD_HEIGHT = 0.028  # below the tool body (r 2 cm, 2 cm above the tip) when it holds a bottom ring
RING_INNER = 0.015
RING_OUTERS = (0.030, 0.035, 0.040)  # ring 0 is the smallest
RING_HEIGHT = 0.01


def stand_parts(colors: tuple[Color, Color, Color]) -> list[dict]:
    """The stand: three 12 cm base sections (coloured ``colors`` along +y) and three rods."""
    sx, sy, sz = STAND_SIZE
    parts: list[dict] = []
    for y, color in zip(ROD_Y, colors, strict=True):
        parts.append({"type": "box", "size": (sx, sy / 3, sz), "position": (0.0, y, sz / 2), "color": color})
    for y in ROD_Y:
        parts.append(
            {
                "type": "cylinder",
                "radius": ROD_RADIUS,
                "height": ROD_HEIGHT,
                "position": (0.0, y, sz + ROD_HEIGHT / 2),
                "color": (120, 90, 70),
            }
        )
    return parts


def ring_parts(outer: float, inner: float = RING_INNER, height: float = RING_HEIGHT, segments: int = 16) -> list[dict]:
    """A ring (annulus) of ``segments`` wall boxes from z = 0 to ``height``; the hole's inradius is ``inner``.

    Visual boxes are as long as the outer polygon's side, so the wall looks closed. Collision boxes
    are as long as the inner polygon's side, so that no two of them overlap: overlapping boxes let a
    ring lying on another catch it on a sideways contact and lift it along when picked.
    """
    tan = math.tan(math.pi / segments)
    mid = (outer + inner) / 2
    visual = shapes.ring_wall_parts(mid, outer - inner, 2 * outer * tan, height, segments, collide=False)
    collision = shapes.ring_wall_parts(mid, outer - inner, 2 * inner * tan, height, segments, visual=False)
    return visual + collision


# Box-corner marker: an L of two thin strips, 2.5 cm legs, 5 mm wide, drawn just outside the corner.
MARKER_LEG = 0.025
MARKER_WIDTH = 0.005
MARKER_THICKNESS = 0.001


def corner_marker_parts(box_size: tuple[float, float, float]) -> list[dict]:
    """Visual-only strips hugging the (+x, +y) corner of a box of ``box_size`` centred on the origin."""
    hx, hy = box_size[0] / 2, box_size[1] / 2
    w, leg, t = MARKER_WIDTH, MARKER_LEG, MARKER_THICKNESS
    strips = [
        ((leg + w, w, t), (hx - leg / 2 + w / 2, hy + w / 2, t / 2)),  # along x, just beyond the +y side
        ((w, leg, t), (hx + w / 2, hy - leg / 2, t / 2)),  # along y, just beyond the +x side
    ]
    return [{"type": "box", "size": size, "position": pos, "collide": False} for size, pos in strips]
