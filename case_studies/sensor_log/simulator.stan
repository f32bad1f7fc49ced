// Newton's law of cooling with an unknown room temperature: a probe at T0
// (deg C) cools towards the ambient Ta (deg C) at rate k (1/min).
// X columns: t (min), T0. theta: k, Ta.
vector simulator(matrix X, vector theta) {
  return theta[2] + (X[:, 2] - theta[2]) .* exp(-theta[1] * X[:, 1]);
}
