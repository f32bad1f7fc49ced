// Counts behind a shield of thickness s (cm, column 1) from a source of
// strength S: S exp(-mu s). theta[1] = S (counts per period without a
// shield), theta[2] = mu (1/cm). S scales the output, so on the log link it
// is a constant: confounded with a constant discrepancy mean
// (stancal.fitting.confounding).
vector simulator(matrix X, vector theta) {
  return theta[1] * exp(-theta[2] * X[:, 1]);
}
