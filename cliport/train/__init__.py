"""Training loop, checkpoint schedule and validation by task success."""
