"""Camera models (RealSense-D415-like views and the oracle camera) and PyBullet rendering."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from cliport.env.bullet import p
from cliport.env.transforms import quat_to_matrix


@dataclass(frozen=True)
class CameraConfig:
    """A pinhole camera: image size (rows, cols), 3x3 intrinsics, pose and depth range.

    The pose is camera-to-world in the robot base frame (camera z forward, y down); ``zrange`` (near,
    far) is the range of valid depth in metres; ``depth_scale`` is the metres per unit of an integer
    depth image (e.g. 0.001 for millimetre PNGs), None for float depth in metres. The fields are also
    the format of ``cameras.json`` for ``cliport-predict`` (``dataclasses.asdict`` writes it).
    """

    image_size: tuple[int, int]
    intrinsics: tuple[float, ...]  # row-major 3x3
    position: tuple[float, float, float]
    rotation: tuple[float, float, float, float]  # quaternion xyzw, camera frame: z forward, y down
    zrange: tuple[float, float] = (0.01, 10.0)
    depth_scale: float | None = None

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the usual name for intrinsics
        return np.array(self.intrinsics, dtype=np.float64).reshape(3, 3)

    def scaled(self, factor: float) -> CameraConfig:
        """The same view rendered at ``factor`` times the resolution (intrinsics scaled to match)."""
        if factor == 1.0:
            return self
        rows, cols = self.image_size
        k = self.K.copy()
        k[:2] *= factor
        return replace(
            self,
            image_size=(int(round(rows * factor)), int(round(cols * factor))),
            intrinsics=tuple(float(c) for c in k.ravel()),
        )


_D415_K = (450.0, 0.0, 320.0, 0.0, 450.0, 240.0, 0.0, 0.0, 1.0)


def realsense_d415() -> list[CameraConfig]:
    """The three Ravens RealSense-D415-like views: front, left, right (480 x 640).

    The reference CLIPort's ``RealSenseD415.CONFIG``: the same image size, intrinsics, positions and
    zrange, and rotations from pybullet's ``getQuaternionFromEuler`` of the same angles, as the reference
    computes them (``euler_to_quat`` can differ from it in the last bit).
    """
    poses = [
        ((1.0, 0.0, 0.75), (math.pi / 4, math.pi, -math.pi / 2)),
        ((0.0, 0.5, 0.75), (math.pi / 4.5, math.pi, math.pi / 4)),
        ((0.0, -0.5, 0.75), (math.pi / 4.5, math.pi, 3 * math.pi / 4)),
    ]
    return [CameraConfig((480, 640), _D415_K, pos, _bullet_quat(rpy)) for pos, rpy in poses]


def _bullet_quat(rpy: tuple[float, float, float]) -> tuple[float, float, float, float]:
    return tuple(float(c) for c in p.getQuaternionFromEuler(rpy))  # type: ignore[return-value]  # tuple() of an iterable has no length in its type


def oracle_camera() -> CameraConfig:
    """Near-orthographic camera straight above the workspace, for task code (not for agents): the
    reference's ``Oracle.CONFIG``."""
    return CameraConfig(
        image_size=(480, 640),
        intrinsics=(63e4, 0.0, 320.0, 0.0, 63e4, 240.0, 0.0, 0.0, 1.0),
        position=(0.5, 0.0, 1000.0),
        rotation=_bullet_quat((0.0, math.pi, -math.pi / 2)),
        zrange=(999.7, 1001.0),
    )


def camera_rotation(config: CameraConfig) -> np.ndarray:
    """3x3 camera-to-world rotation."""
    return quat_to_matrix(config.rotation)


def render(
    config: CameraConfig, client: int, renderer: int, segmentation: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Render one camera.

    Returns color (H, W, 3) uint8, depth (H, W) float32 metres along the optical axis, and the
    segmentation (H, W) int32 of body ids (-1 = nothing) when requested, else None.
    """
    rot = camera_rotation(config)
    look = rot @ np.array([0.0, 0.0, 1.0])
    up = rot @ np.array([0.0, -1.0, 0.0])
    pos = np.asarray(config.position)
    view = p.computeViewMatrix(pos.tolist(), (pos + look).tolist(), up.tolist())
    rows, cols = config.image_size
    fy = config.K[1, 1]
    fov = math.degrees(2 * math.atan((rows / 2) / fy))
    near, far = config.zrange
    proj = p.computeProjectionMatrixFOV(fov, cols / rows, near, far)
    flags = 0 if segmentation else p.ER_NO_SEGMENTATION_MASK
    _, _, color, zbuffer, segm = p.getCameraImage(
        width=cols,
        height=rows,
        viewMatrix=view,
        projectionMatrix=proj,
        shadow=0,
        flags=flags,
        renderer=renderer,
        physicsClientId=client,
    )
    color = np.asarray(color, dtype=np.uint8).reshape(rows, cols, 4)[..., :3]
    z = np.asarray(zbuffer, dtype=np.float32).reshape(rows, cols)
    depth = (2.0 * near * far / (far + near - (2.0 * z - 1.0) * (far - near))).astype(np.float32)
    seg = np.asarray(segm, dtype=np.int32).reshape(rows, cols) if segmentation else None
    return color, depth, seg
