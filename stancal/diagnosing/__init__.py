"""Questions asked of fits: the gap diagnosis, method comparison, scoring
and simulation-based calibration."""
