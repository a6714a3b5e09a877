import math

import numpy as np
import pybullet as p
import pytest

from cliport.env import heightmap as hm
from cliport.env import shapes
from cliport.env.environment import ActionError, EnvConfig, Environment
from cliport.env.primitives import PickPlaceSettings, pick_place
from cliport.env.transforms import quat_to_yaw, yaw_to_quat


class RandomBlocks:
    """A minimal task: a few cubes at seeded random poses."""

    max_steps = 3
    end_effector = "suction"
    primitive = "pick_place"
    primitive_settings = PickPlaceSettings()

    def reset(self, env, rng):
        self.blocks = []
        for _ in range(3):
            xy = rng.uniform([0.35, -0.3], [0.65, 0.3])
            pose = ((float(xy[0]), float(xy[1]), 0.02), yaw_to_quat(float(rng.uniform(0, math.pi))))
            self.blocks.append(env.add_object(shapes.box(env.client, (0.04, 0.04, 0.04), pose, color=(255, 87, 89))))

    def reward(self):
        return 0.0, {"blocks": len(self.blocks)}

    def done(self):
        return False

    @property
    def lang_goal(self):
        return "look at the red blocks"


@pytest.fixture(scope="module")
def env():
    e = Environment(EnvConfig.defaults(camera_scale=0.5))
    yield e
    e.close()


def _place_cube(env, xy, size=0.04):
    body = shapes.box(env.client, (size,) * 3, ((xy[0], xy[1], size / 2), (0, 0, 0, 1)), color=(255, 0, 0))
    env.add_object(body)
    env.settle()
    return body


@pytest.mark.parametrize("renderer", ["auto"])
def test_cube_appears_at_its_pixel_with_its_height(renderer):
    with Environment(EnvConfig.defaults(renderer=renderer)) as env:
        for xy in [(0.5, 0.0), (0.35, -0.3), (0.62, 0.27)]:
            env.reset(0)
            _place_cube(env, xy)
            obs = env.observe()
            assert obs["color"].shape == (320, 160, 3) and obs["color"].dtype == np.uint8
            assert obs["height"].shape == (320, 160) and obs["height"].dtype == np.float32
            top = obs["height"] > 0.02
            rows, cols = np.nonzero(top)
            u, v = hm.xyz_to_pix(xy)
            assert abs(rows.mean() - u) <= 1.0 and abs(cols.mean() - v) <= 1.0
            assert abs(np.median(obs["height"][top]) - 0.04) < 0.003
            assert 140 <= top.sum() <= 240  # a 4 cm square is ~164 cells of 3.125 mm, plus side faces
            assert obs["color"][u, v, 0] > 200 and obs["color"][u, v, 1] < 50


_EGL_CHECK = """
import json
import numpy as np
from cliport.env import heightmap as hm, shapes
from cliport.env.environment import EnvConfig, Environment
with Environment(EnvConfig.defaults(renderer="egl")) as env:
    env.reset(0)
    env.add_object(shapes.box(env.client, (0.04,) * 3, ((0.35, -0.3, 0.02), (0, 0, 0, 1)), color=(255, 0, 0)))
    env.settle()
    a, b = env.observe(), env.observe()
rows, cols = np.nonzero(a["height"] > 0.02)
top = a["height"][a["height"] > 0.02]
same = bool(np.array_equal(a["color"], b["color"]))
out = {"renderer": env.renderer_name, "u": rows.mean(), "v": cols.mean(), "height": float(np.median(top))}
print(json.dumps({**out, "pix": hm.xyz_to_pix((0.35, -0.3)), "same": same}))
"""


def test_egl_renderer_in_its_own_process():
    """EGL (Mesa's llvmpipe on CPU machines) in a subprocess: its LLVM must not meet triton in pytest's."""
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", _EGL_CHECK], capture_output=True, text=True, timeout=300)
    if "eglRenderer plugin did not load" in run.stderr:
        pytest.skip("PyBullet's EGL plugin does not load on this machine")
    assert run.returncode == 0, run.stderr[-2000:]
    import json

    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["renderer"].startswith("egl")
    assert abs(out["u"] - out["pix"][0]) <= 1 and abs(out["v"] - out["pix"][1]) <= 1
    assert abs(out["height"] - 0.04) < 0.003 and out["same"]


def test_pick_and_place_moves_and_rotates_block(env):
    env.reset(0)
    start, goal = (0.4, 0.2), (0.6, -0.2)
    block = _place_cube(env, start)
    yaw = math.radians(40)
    action = {"pose0": ((*start, 0.04), (0, 0, 0, 1)), "pose1": ((*goal, 0.04), yaw_to_quat(yaw))}
    _, reward, done, info = env.step(action)
    pos, quat = p.getBasePositionAndOrientation(block, physicsClientId=env.client)
    assert info["grasped"] and info["reached"]
    assert np.linalg.norm(np.subtract(pos[:2], goal)) < 0.01
    assert abs(math.degrees(quat_to_yaw(quat) - yaw)) < 15
    assert reward == 0.0 and not done and info["lang_goal"] is None


def test_low_carry_approaches_and_leaves_from_above(env):
    """Rope settings carry 2 cm high, but the tool still comes down from 0.32 m and leaves to 0.32 m."""
    env.reset(0)
    start, goal = (0.45, 0.1), (0.55, -0.1)
    block = _place_cube(env, start)
    moves = []
    movep = env.robot.movep

    def logged(pose, speed=0.01, budget=2400):
        reached = movep(pose, speed, budget)
        moves.append((pose[0][2], speed, env.robot.tip_pose()[0][2]))
        return reached

    env.robot.movep = logged
    try:
        settings = PickPlaceSettings(height=0.02, speed=0.003)
        out = pick_place(env.robot, env.ee, ((*start, 0.04), (0, 0, 0, 1)), ((*goal, 0.04), (0, 0, 0, 1)), settings)
    finally:
        del env.robot.movep
    assert out["grasped"] and out["reached"]
    assert moves[0][0] == pytest.approx(0.04 + 0.32) and moves[0][1] == 0.01  # approach from above, fast
    assert moves[-1][0] == pytest.approx(0.04 + 0.32) and moves[-1][2] > 0.3  # leave upwards
    carried = [m for m in moves if m[1] == 0.003]
    assert carried and max(m[0] for m in carried) == pytest.approx(0.04 + 0.02)  # lifted only 2 cm
    pos, _ = p.getBasePositionAndOrientation(block, physicsClientId=env.client)
    assert np.linalg.norm(np.subtract(pos[:2], goal)) < 0.01


@pytest.mark.parametrize("xy", [(0.25, -0.5), (0.25, 0.5), (0.75, -0.5), (0.75, 0.5), (0.5, 0.0)])
def test_arm_reaches_workspace_corners(env, xy):
    env.reset(0)
    target = ((xy[0], xy[1], 0.05), (0.0, 0.0, 0.0, 1.0))
    assert env.robot.movep(target)
    tip = env.robot.tip_pose()
    assert np.linalg.norm(np.subtract(tip[0], target[0])) < 0.01
    assert abs(np.dot(tip[1], target[1])) > math.cos(math.radians(2) / 2)


def test_home_pose_matches_reference(env):
    env.reset(0)
    pos, quat = env.robot.tip_pose()
    assert np.allclose(pos, (0.487, 0.109, 0.312), atol=0.002)
    assert np.allclose(np.abs(quat), (0, 0, 0, 1), atol=1e-6)


def test_same_seed_same_observation():
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=RandomBlocks()) as env:
        a = env.reset(7)
        b = env.reset(7)
        c = env.reset(8)
    assert np.array_equal(a["color"], b["color"]) and np.array_equal(a["height"], b["height"])
    assert not np.array_equal(a["height"], c["height"])


def test_task_plugs_in_and_info_has_language(env):
    env.set_task(RandomBlocks())
    try:
        obs = env.reset(3)
        assert (obs["height"] > 0.03).sum() > 200  # three cubes
        _, _, done, info = env.step(None)
        assert info["lang_goal"] == "look at the red blocks" and info["blocks"] == 3 and not done
        for _ in range(2):
            _, _, done, _ = env.step(None)
        assert done  # max_steps reached
    finally:
        env.set_task(None)


def test_raw_images_on_request(env):
    env.reset(0)
    obs = env.observe(raw_images=True)
    assert len(obs["cameras"]) == 3
    assert obs["cameras"][0]["color"].shape == (240, 320, 3)
    assert obs["cameras"][0]["depth"].shape == (240, 320)
    assert "cameras" not in env.observe()


@pytest.mark.parametrize(
    "action, field",
    [
        ({"pose0": ((0.5, 0.0), (0, 0, 0, 1)), "pose1": ((0.5, 0, 0.02), (0, 0, 0, 1))}, "pose0 position"),
        ({"pose0": ((0.5, 0.0, 0.02), (0, 0, 0, 1)), "pose1": ((0.5, np.nan, 0.02), (0, 0, 0, 1))}, "pose1"),
        ({"pose0": ((0.5, 0.0, 0.02), (0, 0, 1)), "pose1": ((0.5, 0, 0.02), (0, 0, 0, 1))}, "pose0 quaternion"),
        ({"pose0": ((0.9, 0.0, 0.02), (0, 0, 0, 1)), "pose1": ((0.5, 0, 0.02), (0, 0, 0, 1))}, "pose0 x=0.900"),
        ({"pose0": ((0.5, 0.0, 0.02), (0, 0, 0, 1)), "pose1": ((0.5, -0.7, 0.02), (0, 0, 0, 1))}, "pose1 y="),
        ({"pose0": ((0.5, 0.0, 0.02), (0, 0, 0, 1))}, "pose1"),
        ("pick here", "dict"),
    ],
)
def test_bad_actions_name_the_field(env, action, field):
    env.reset(0)
    with pytest.raises(ActionError, match=field.replace("(", r"\(")):
        env.step(action)


def test_bad_config_is_reported():
    with pytest.raises(ValueError, match="renderer"):
        Environment(EnvConfig.defaults(renderer="vulkan"))
    with pytest.raises(ValueError, match="camera_scale"):
        Environment(EnvConfig.defaults(camera_scale=0))
    with pytest.raises(ValueError, match=r"unknown EnvConfig key\(s\) .camrea_scale. \(did you mean .camera_scale"):
        EnvConfig.defaults(camrea_scale=0.5)
