"""Console scripts: cliport-demos, cliport-train, cliport-eval, cliport-tasks."""
