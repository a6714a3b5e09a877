"""Demonstrations, between the simulator and training: the seed protocol of the train, val and test episodes
(``seeds``), running one episode with any policy (``rollout``), generating the experts' demos in parallel and
resumably (``generate``, ``cliport-demos``), one compressed file per episode (``episode_io``), the training dataset
of steps with their SE(2) augmentation (``dataset``, ``augment``), and datasets of the reference CLIPort and Ravens
imported as episode files (``ravens_import``). Nothing here imports an agent.
"""
