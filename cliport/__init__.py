"""CLIPort and Transporter Networks on a PyBullet rebuild of the Ravens tabletop tasks."""

__version__ = "0.1.0"
