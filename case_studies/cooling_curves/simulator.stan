/**
 * Newton's law of cooling read by a probe with an offset. Rows of X are
 * (T0, t): the cool-down's start temperature (deg C) and the reading's time
 * (min); theta = (k, Ta, offset): the cooling rate (1/min), the ambient
 * temperature (deg C) and this cool-down's probe offset (deg C).
 */
vector simulator(matrix X, vector theta) {
  return theta[2] + (X[:, 1] - theta[2]) .* exp(-theta[1] * X[:, 2]) + theta[3];
}
