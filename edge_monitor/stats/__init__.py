"""Statistics with no knowledge of robots: streaming KDE and KL distance, nominal mixture densities,
bias-change EM, GLR tests and the per-quantity sequential detector (docs/ALGORITHMS.md §4–§6)."""
