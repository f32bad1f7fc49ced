// Expected counts of a detector at distance d (m, column 1) behind a shield
// of thickness s (cm, column 2) in one counting period, from a point source of
// unknown strength: the inverse-square law times Beer-Lambert attenuation.
// theta[1] = S, the source strength (counts per period at 1 m, no shield);
// theta[2] = mu, the shield's attenuation coefficient (1/cm).
// Under the log link S adds log S at every point: a constant, confounded with
// a constant in the discrepancy's mean (stancal/fitting/confounding.py).
vector simulator(matrix X, vector theta) {
  return theta[1] * exp(-theta[2] * X[:, 2]) ./ square(X[:, 1]);
}
