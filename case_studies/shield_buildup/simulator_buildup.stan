// The narrow-beam simulator (../detector_counts/simulator.stan) times the linear build-up factor
// B = 1 + a mu s of a broad beam: photons scattered in the shield that still
// reach the detector.
// theta[1] = mu (1/cm), theta[2] = a (dimensionless).
vector simulator(matrix X, vector theta) {
  vector[rows(X)] mu_s = theta[1] * X[:, 2];
  return 2000 * exp(-mu_s) .* (1 + theta[2] * mu_s) ./ square(X[:, 1]);
}
