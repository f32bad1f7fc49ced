/**
 * Newton's law of cooling. Rows of X are (T0, t): the cup's start
 * temperature (deg C) and the reading's time (min); theta = (k, Ta): the
 * cooling rate (1/min) and the room temperature (deg C).
 */
vector simulator(matrix X, vector theta) {
  return theta[2] + (X[:, 1] - theta[2]) .* exp(-theta[1] * X[:, 2]);
}
