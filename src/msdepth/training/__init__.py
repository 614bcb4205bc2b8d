"""Training a depth network (one process or several), checkpoints and resume."""
