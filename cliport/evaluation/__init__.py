"""Evaluating agents in the simulator: success scores, confidence intervals, videos and heatmaps."""
