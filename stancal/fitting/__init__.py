"""From a problem to a result: the plan, stage 1, sampling, post-fit checks,
prediction, L2 projection, and many fits on Dask."""
