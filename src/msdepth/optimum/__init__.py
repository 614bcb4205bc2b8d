"""The losses' own optimum: disparities that minimise a variant's objective, no network."""
