import tempfile

import pybullet as p
import pytest

from cliport.env import shapes


@pytest.fixture
def client():
    c = p.connect(p.DIRECT)
    yield c
    p.disconnect(c)


def test_compound_with_many_parts_keeps_every_part(client):
    """Long compound URDFs (kit boards, piles of parts) load with every element."""
    parts = [
        {"type": "box", "size": (0.01,) * 3, "position": (0.012 * (k % 20), 0.012 * (k // 20), 0.0)} for k in range(200)
    ]
    with tempfile.TemporaryDirectory() as d:
        body = shapes.compound(client, d, parts, ((0.5, 0.0, 0.1), (0, 0, 0, 1)))
        collisions = p.getCollisionShapeData(body, -1, physicsClientId=client)
        visuals = p.getVisualShapeData(body, physicsClientId=client)
    assert len(collisions) == 200
    assert len(visuals) == 200


def test_box_is_where_it_was_put(client):
    body = shapes.box(client, (0.04, 0.04, 0.04), ((0.4, 0.1, 0.02), (0, 0, 0, 1)), color=(255, 0, 0))
    pos, _ = p.getBasePositionAndOrientation(body, physicsClientId=client)
    assert pos == pytest.approx((0.4, 0.1, 0.02))
