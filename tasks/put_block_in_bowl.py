"""put-block-in-bowl-{seen,unseen}-colors: put the blocks of one colour in bowls of another colour."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import BLOCK, BOWL, BOWL_TOLERANCE
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.registry import register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

N_DISTRACTORS = 6


class _PutBlockInBowl(Task):
    """1-3 bowls of the place colour, 1..bowls blocks of the pick colour, six distractor blocks/bowls.

    One goal step holds every target block (each in a different bowl, within 5 cm of its centre as in
    the reference; block yaw ignored), so the reward is 1/n per block placed; ``max_steps`` is the
    number of blocks + 1.
    """

    unseen = False
    max_steps = 10
    place_yaw_informative = False  # round bowls: the expert places at a bowl's random yaw
    done_sentence = "done placing blocks in bowls."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        palette = split_colors(self.mode, self.unseen)
        n_bowls = int(rng.integers(1, 4))
        n_blocks = int(rng.integers(1, n_bowls + 1))
        pick, place = (palette[int(k)] for k in rng.permutation(len(palette))[:2])
        bowl_poses = []
        self.colors_seen: dict[str, list] = {"blocks": [], "bowls": []}  # (colour, body or pose) of each
        for _ in range(n_bowls):
            pose = self.random_pose(BOWL, margin=0.01)
            assert pose is not None, "three bowls always fit on an empty table"
            pose = at_height(pose)
            env.add_object(shapes.bowl(env.client, env.asset_dir, pose, COLORS[place]), "fixed")
            bowl_poses.append(pose)
            self.colors_seen["bowls"].append((place, pose))
        blocks = []
        for _ in range(n_blocks):
            pose = self.random_pose(BLOCK)
            assert pose is not None, "the target blocks always fit beside the bowls"
            blocks.append(env.add_object(shapes.box(env.client, BLOCK, pose, COLORS[pick])))
            self.colors_seen["blocks"].append((pick, blocks[-1]))
        others = [c for c in palette if c not in (pick, place)]
        for k in range(N_DISTRACTORS):
            is_block = rng.random() > 0.5
            pose = self.random_pose(BLOCK if is_block else BOWL, margin=0.01)
            if pose is None:
                continue
            name = others[k % len(others)]
            if is_block:
                body = env.add_object(shapes.box(env.client, BLOCK, pose, COLORS[name]))
                self.colors_seen["blocks"].append((name, body))
            else:
                pose = at_height(pose)
                env.add_object(shapes.bowl(env.client, env.asset_dir, pose, COLORS[name]), "fixed")
                self.colors_seen["bowls"].append((name, pose))
        self.max_steps = n_blocks + 1
        self.add_goal(self.colors_step(pick, place, f"put the {pick} blocks in a {place} bowl"))

    def colors_step(self, pick: str, place: str, lang_goal: str | None = None) -> GoalStep:
        """The goal step of putting every block of colour ``pick`` in a different bowl of colour ``place``."""
        blocks = [body for name, body in self.colors_seen["blocks"] if name == pick]
        bowls = [pose for name, pose in self.colors_seen["bowls"] if name == place]
        return GoalStep(
            objects=blocks,
            matches=np.ones((len(blocks), len(bowls))),
            targets=bowls,
            share=1.0,
            symmetries=[0.0] * len(blocks),
            rotations=True,
            tolerance=BOWL_TOLERANCE,
            lang_goal=lang_goal,
        )

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """Every (block colour, bowl colour) pair the scene leaves possible, each done in full before the next.
        Possible: the named block colour is never a bowl's and the named bowl colour never a block's (distractors
        take the other colours), so a colour seen on both is ruled out. Likeliest first: the named colours come on
        1-3 blocks and bowls, a distractor's mostly on one, so pairs whose colours are on more objects go first
        (ties in a random order)."""
        blocks = [name for name, _ in self.colors_seen["blocks"]]
        bowls = [name for name, _ in self.colors_seen["bowls"]]
        pairs = sorted((pick, place) for pick in set(blocks) - set(bowls) for place in set(bowls) - set(blocks))
        shuffled = [pairs[int(k)] for k in rng.permutation(len(pairs))]
        shuffled.sort(key=lambda pair: -(blocks.count(pair[0]) + bowls.count(pair[1])))
        return [self.colors_step(*pair) for pair in shuffled]


PutBlockInBowlSeenColors, PutBlockInBowlUnseenColors = register_splits(
    _PutBlockInBowl, "put-block-in-bowl-seen-colors", "put-block-in-bowl-unseen-colors"
)
