"""What a fit leaves: the result objects (data only), summaries, modes and
sampler diagnostics."""
