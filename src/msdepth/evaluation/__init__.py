"""Inference, depth, the evaluation suites and metrics, baselines, pose evaluation."""
