"""The simulated workcell: UR5 arm, end effectors, cameras and top-down observations.

Nothing in this package imports torch.
"""
