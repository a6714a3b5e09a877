"""UR5 arm and end-effector URDFs generated in code from the standard UR5 dimensions.

Link shapes are capsules and cylinders; the kinematics follow the published UR5 parameters
(d1 0.089159, a2 0.425, a3 0.39225, d4 0.10915, d5 0.09465, d6 0.0823). A tool frame ("tip") sits
0.12 m past the flange; its identity orientation means the tool points straight down.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass

D1, A2, A3, D4, D5, D6 = 0.089159, 0.425, 0.39225, 0.10915, 0.09465, 0.0823
SHOULDER_OFFSET, ELBOW_OFFSET = 0.13585, 0.1197  # lateral link offsets; their difference + 0.093 = d4
WRIST2_OFFSET = D4 - SHOULDER_OFFSET + ELBOW_OFFSET
TOOL_LENGTH = 0.12
HOME_JOINTS = tuple(c * math.pi for c in (-1.0, -0.5, 0.5, -0.5, -0.5, 0.0))
ARM_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
TIP_LINK = "tip"
SPATULA_BLADE = (0.005, 0.05, 0.11)  # x (push direction), y (blade width), z (height) in metres

_GREY = "0.6 0.6 0.62 1"
_DARK = "0.25 0.25 0.27 1"


@dataclass(frozen=True)
class _Link:
    name: str
    mass: float
    shapes: tuple[str, ...]  # <visual>/<collision> pairs, already formatted


def _material_name(rgba: str) -> str:
    return "rgba_" + rgba.replace(" ", "_").replace(".", "p")


def _cylinder(radius: float, length: float, xyz: str, rpy: str, color: str, collide: bool = True) -> str:
    geom = f'<geometry><cylinder radius="{radius}" length="{length}"/></geometry>'
    origin = f'<origin xyz="{xyz}" rpy="{rpy}"/>'
    out = f'<visual>{origin}{geom}<material name="{_material_name(color)}"><color rgba="{color}"/></material></visual>'
    if collide:
        out += f"<collision>{origin}{geom}</collision>"
    return out


def _box(size: tuple[float, float, float], xyz: str, color: str) -> str:
    geom = f'<geometry><box size="{size[0]} {size[1]} {size[2]}"/></geometry>'
    origin = f'<origin xyz="{xyz}" rpy="0 0 0"/>'
    return (
        f'<visual>{origin}{geom}<material name="{_material_name(color)}"><color rgba="{color}"/></material></visual>'
        f"<collision>{origin}{geom}</collision>"
    )


def _link(link: _Link) -> str:
    i = max(link.mass * 0.004, 1e-5)
    inertial = (
        f'<inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="{link.mass}"/>'
        f'<inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="{i}"/></inertial>'
    )
    return f'<link name="{link.name}">{inertial}{"".join(link.shapes)}</link>'


def _joint(name: str, parent: str, child: str, xyz: str, rpy: str, axis: str | None, effort: float = 150) -> str:
    if axis is None:
        return (
            f'<joint name="{name}" type="fixed"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/></joint>'
        )
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis}"/>'
        f'<limit lower="{-2 * math.pi}" upper="{2 * math.pi}" effort="{effort}" velocity="3.15"/>'
        f'<dynamics damping="0.0" friction="0.0"/></joint>'
    )


# The base is turned by pi about z so that the home pose faces +x, the workspace side.
# Rotation of the tool frame relative to the flange ("ee_link") so that, at the home joints, the
# tool frame's world orientation is the identity (pointing straight down). Derived by composing the
# chain's joint rotations at HOME_JOINTS; checked in tests/env/test_robot.py.
_TIP_RPY = f"0 {-math.pi / 2} 0"


def ur5_urdf(end_effector: str = "suction") -> str:
    """URDF text of the UR5 with a suction cup ("suction") or a spatula ("spatula") on its flange."""
    if end_effector not in ("suction", "spatula"):
        raise ValueError(f"end_effector must be 'suction' or 'spatula', got {end_effector!r}")
    h = math.pi / 2
    links = [
        _Link("world", 0.0, ()),
        _Link("base_link", 4.0, (_cylinder(0.075, D1, f"0 0 {D1 / 2}", "0 0 0", _DARK),)),
        _Link(
            "shoulder_link", 3.7, (_cylinder(0.06, SHOULDER_OFFSET, f"0 {SHOULDER_OFFSET / 2} 0", f"{h} 0 0", _GREY),)
        ),
        _Link("upper_arm_link", 8.4, (_cylinder(0.054, A2, f"0 0 {A2 / 2}", "0 0 0", _GREY),)),
        _Link("forearm_link", 2.3, (_cylinder(0.04, A3, f"0 0 {A3 / 2}", "0 0 0", _GREY),)),
        _Link("wrist_1_link", 1.2, (_cylinder(0.04, WRIST2_OFFSET, f"0 {WRIST2_OFFSET / 2} 0", f"{h} 0 0", _DARK),)),
        _Link("wrist_2_link", 1.2, (_cylinder(0.04, D5, f"0 0 {D5 / 2}", "0 0 0", _DARK),)),
        _Link("wrist_3_link", 0.19, (_cylinder(0.04, D6, f"0 {D6 / 2} 0", f"{h} 0 0", _GREY),)),
        _Link("ee_link", 0.01, ()),
    ]
    joints = [
        _joint("world_joint", "world", "base_link", "0 0 0", f"0 0 {math.pi}", None),
        _joint(ARM_JOINTS[0], "base_link", "shoulder_link", f"0 0 {D1}", "0 0 0", "0 0 1"),
        _joint(ARM_JOINTS[1], "shoulder_link", "upper_arm_link", f"0 {SHOULDER_OFFSET} 0", f"0 {h} 0", "0 1 0"),
        _joint(ARM_JOINTS[2], "upper_arm_link", "forearm_link", f"0 {-ELBOW_OFFSET} {A2}", "0 0 0", "0 1 0"),
        _joint(ARM_JOINTS[3], "forearm_link", "wrist_1_link", f"0 0 {A3}", f"0 {h} 0", "0 1 0", 28),
        _joint(ARM_JOINTS[4], "wrist_1_link", "wrist_2_link", f"0 {WRIST2_OFFSET} 0", "0 0 0", "0 0 1", 28),
        _joint(ARM_JOINTS[5], "wrist_2_link", "wrist_3_link", f"0 0 {D5}", "0 0 0", "0 1 0", 28),
        _joint("ee_fixed_joint", "wrist_3_link", "ee_link", f"0 {D6} 0", f"0 0 {h}", None),
    ]
    # The tool frame: z up (away from the table when pointing down); the tool extends along its -z.
    links.append(_Link("tool_frame", 0.01, ()))
    joints.append(_joint("tool_frame_joint", "ee_link", "tool_frame", "0 0 0", _TIP_RPY, None))
    if end_effector == "suction":
        body = _cylinder(0.02, TOOL_LENGTH - 0.02, f"0 0 {-(TOOL_LENGTH - 0.02) / 2}", "0 0 0", _DARK)
        tip = _cylinder(0.006, 0.02, "0 0 0.01", "0 0 0", "0.1 0.1 0.1 1")
    else:
        blade_h = SPATULA_BLADE[2]
        body = _cylinder(0.015, TOOL_LENGTH - blade_h, f"0 0 {-(TOOL_LENGTH - blade_h) / 2}", "0 0 0", _DARK)
        tip = _box(SPATULA_BLADE, f"0 0 {blade_h / 2}", "0.8 0.8 0.8 1")
    links.append(_Link("tool_body", 0.05, (body,)))
    joints.append(_joint("tool_body_joint", "tool_frame", "tool_body", "0 0 0", "0 0 0", None))
    links.append(_Link(TIP_LINK, 0.01, (tip,)))
    joints.append(_joint("tip_joint", "tool_frame", TIP_LINK, f"0 0 {-TOOL_LENGTH}", "0 0 0", None))
    body_xml = "".join(_link(link) for link in links) + "".join(joints)
    return f'<?xml version="1.0"?><robot name="ur5_{end_effector}">{body_xml}</robot>'


def write_urdf(text: str, name: str, directory: str | None = None) -> str:
    """Write URDF text to ``directory`` and return the file path.

    Without ``directory`` the file goes to a fresh subfolder of the process's asset folder, which is
    removed when the process ends (see :mod:`cliport.env.assets`). The write is atomic, so a reader
    never sees half a file.
    """
    if directory is None:
        from cliport.env import assets

        directory = assets.new_asset_dir("urdf-")
    path = os.path.join(directory, f"{name}.urdf")
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)
    return path
