"""The DVC pipeline's paths and stage plumbing, and dvc.yaml's generated parts."""
