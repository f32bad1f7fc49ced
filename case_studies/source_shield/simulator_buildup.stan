// The narrow-beam simulator (simulator.stan) times the linear build-up factor
// B = 1 + a mu s of a broad beam: photons scattered in the shield that still
// reach the detector (Shultis & Faw, "Radiation Shielding", ch. 8).
// theta[1] = S (counts per period at 1 m), theta[2] = mu (1/cm), theta[3] = a.
vector simulator(matrix X, vector theta) {
  vector[rows(X)] mu_s = theta[2] * X[:, 2];
  return theta[1] * exp(-mu_s) .* (1 + theta[3] * mu_s) ./ square(X[:, 1]);
}
