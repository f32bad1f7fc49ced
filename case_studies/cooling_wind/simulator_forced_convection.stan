/**
 * Newton's law of cooling in a draught: forced convection raises the
 * cooling rate to k (1 + c wind). Rows of X are (T0, wind, t), wind in m/s;
 * theta = (k, Ta, c).
 */
vector simulator(matrix X, vector theta) {
  vector[rows(X)] rate = theta[1] * (1 + theta[3] * X[:, 2]);
  return theta[2] + (X[:, 1] - theta[2]) .* exp(-rate .* X[:, 3]);
}
