"""The one typed config: params.yaml's schema and checks, and each loss variant's settings."""
