"""Comparison between variants (bootstrap intervals), the results page and the figures."""
