"""The comparison as data: paired statistics over runs and seeds, the verdict's rows, each loss's own best."""
