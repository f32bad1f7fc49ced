// Expected counts of a detector at distance d (m, column 1) behind a shield
// of thickness s (cm, column 2) in one counting period, from a point source:
// the inverse-square law times Beer-Lambert attenuation in the shield.
// theta[1] = mu, the shield's attenuation coefficient (1/cm).
vector simulator(matrix X, vector theta) {
  return 2000 * exp(-theta[1] * X[:, 2]) ./ square(X[:, 1]);
}
