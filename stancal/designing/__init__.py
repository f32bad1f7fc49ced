"""The design loop: history matching in waves and the next simulator runs
and experiments (review sections 5 and 7)."""
