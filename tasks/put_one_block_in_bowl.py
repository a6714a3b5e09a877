"""put-one-block-in-bowl-{seen,unseen}-colors: the language lesson's task, put-block-in-bowl made small.

Three blocks and two bowls, five different colours; the instruction names one block and one bowl ("put the
red block in the green bowl"), so only the sentence tells which of the three blocks to pick and which of the
two bowls to place it in. One pick and place solves it. Colours come from CLIPort's seen/unseen splits, as in
put-block-in-bowl. It exists so that a language-conditioned agent can learn to follow colour instructions on
a laptop (``scripts/quickstart.py --language``); put-block-in-bowl has 1-3 target blocks among six distractors.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import BLOCK, BOWL, BOWL_TOLERANCE
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.registry import register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

N_BLOCKS = 3
N_BOWLS = 2
TEMPLATE = "put the {} block in the {} bowl"


class _PutOneBlockInBowl(Task):
    """Three blocks and two bowls of five different colours; one named block into one named bowl.

    ``block_colors`` maps each block's colour to its body id and ``bowl_colors`` each bowl's colour to its
    pose, and ``goal_block``/``goal_bowl`` are the colours the instruction names, so that an instruction
    naming another block can be made (``instruction_for``) and checked.
    """

    unseen = False
    offers_instruction_variants = True
    max_steps = 2  # one step solves it; one more, as put-block-in-bowl allows blocks + 1
    place_yaw_informative = False  # round bowls
    done_sentence = "done placing the block in the bowl."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        palette = split_colors(self.mode, self.unseen)
        chosen = [palette[int(k)] for k in rng.permutation(len(palette))[: N_BLOCKS + N_BOWLS]]
        block_names, bowl_names = chosen[:N_BLOCKS], chosen[N_BLOCKS:]
        self.bowl_colors: dict[str, tuple] = {}
        for name in bowl_names:
            pose = self.random_pose(BOWL, margin=0.01)
            assert pose is not None, "two bowls always fit on an empty table"
            pose = at_height(pose)
            env.add_object(shapes.bowl(env.client, env.asset_dir, pose, COLORS[name]), "fixed")
            self.bowl_colors[name] = pose
        self.block_colors: dict[str, int] = {}
        for name in block_names:
            pose = self.random_pose(BLOCK)
            assert pose is not None, "three blocks always fit beside two bowls"
            self.block_colors[name] = env.add_object(shapes.box(env.client, BLOCK, pose, COLORS[name]))
        self.goal_block, self.goal_bowl = block_names[0], bowl_names[0]
        self.add_goal(self._goal(self.goal_block, self.goal_bowl))

    def _goal(self, block: str, bowl: str) -> GoalStep:
        return GoalStep(
            objects=[self.block_colors[block]],
            matches=np.ones((1, 1)),
            targets=[self.bowl_colors[bowl]],
            share=1.0,
            symmetries=[0.0],
            rotations=True,
            tolerance=BOWL_TOLERANCE,
            lang_goal=TEMPLATE.format(block, bowl),
        )

    def instruction_variants(self, obs: dict | None = None) -> list[tuple[str, dict[str, Any]]]:
        """The other five (block, bowl) instructions of the scene, blocks in scene order then bowls, each with
        the oracle's action from this state; every oracle call starts from the same random state."""
        if not self.goals:
            return []
        goals, state = self.goals, self.rng.bit_generator.state
        height, ids = self.env.oracle_heightmap()
        variants = []
        try:
            for block in self.block_colors:
                for bowl in self.bowl_colors:
                    if (block, bowl) == (self.goal_block, self.goal_bowl):
                        continue
                    self.goals = [self._goal(block, bowl)]
                    self.rng.bit_generator.state = state
                    action = self.oracle_act_on(height, ids)
                    if action is None:
                        raise RuntimeError(f"the oracle found no action for {TEMPLATE.format(block, bowl)!r}")
                    variants.append((TEMPLATE.format(block, bowl), action))
        finally:
            self.goals = goals
            self.rng.bit_generator.state = state
        return variants

    def instruction_for(self, block: str, bowl: str) -> str:
        """The instruction naming ``block`` and ``bowl`` (colours present in the scene)."""
        if block not in self.block_colors or bowl not in self.bowl_colors:
            raise ValueError(
                f"no {block} block and {bowl} bowl in this scene (blocks: {', '.join(self.block_colors)}; "
                f"bowls: {', '.join(self.bowl_colors)})"
            )
        return TEMPLATE.format(block, bowl)


PutOneBlockInBowlSeenColors, PutOneBlockInBowlUnseenColors = register_splits(
    _PutOneBlockInBowl, "put-one-block-in-bowl-seen-colors", "put-one-block-in-bowl-unseen-colors"
)
