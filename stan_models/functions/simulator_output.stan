/**
 * The user's simulator at the physical points, standardised like y, with
 * checks that name what to fix. Needs simulator(matrix, vector) defined
 * before this file is included.
 *
 * @param X inputs, one row per point, original units
 * @param theta calibration parameters, original units
 * @param y_center the standardisation applied to y
 * @param y_scale the standardisation applied to y
 * @return (simulator(X, theta) - y_center) / y_scale
 */
vector standardized_simulator(matrix X, vector theta, real y_center, real y_scale) {
  vector[rows(X)] f = simulator(X, theta);
  if (rows(f) != rows(X)) {
    reject("simulator(X, theta) returned ", rows(f), " values for ", rows(X),
           " rows of X; it must return one value per row of X");
  }
  for (i in 1:rows(X)) {
    if (is_nan(f[i]) || is_inf(f[i])) {
      reject("simulator(X, theta) returned ", f[i], " at row ", i, " of X = ", X[i],
             " with theta = ", theta, "; make it finite over the whole theta box");
    }
  }
  return (f - y_center) / y_scale;
}

/**
 * Derivatives of the standardised simulator with respect to theta, by
 * central differences (Stan has no nested autodiff). Used by the orthogonal
 * GP (review eq. 12). Steps of 1e-5 of theta's range: truncation error
 * ~1e-10 and round-off ~1e-11, relative; within 1e-5 of a bound the step is
 * cut at the bound, so the simulator is never called outside the theta box.
 *
 * @param X inputs, one row per point, original units
 * @param theta calibration parameters, original units
 * @param theta_lower the theta box
 * @param theta_upper the theta box
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return matrix of d f(x_r, theta) / d theta_j, rows(X) x rows(theta)
 */
matrix simulator_theta_derivatives(matrix X, vector theta, vector theta_lower, vector theta_upper,
                          real y_center, real y_scale) {
  int q = rows(theta);
  matrix[rows(X), q] G;
  for (j in 1:q) {
    real step = 1e-5 * (theta_upper[j] - theta_lower[j]);
    vector[q] above = theta;
    vector[q] below = theta;
    above[j] = fmin(theta[j] + step, theta_upper[j]);
    below[j] = fmax(theta[j] - step, theta_lower[j]);
    G[:, j] = (standardized_simulator(X, above, y_center, y_scale)
               - standardized_simulator(X, below, y_center, y_scale)) / (above[j] - below[j]);
  }
  return G;
}

/**
 * The weights A of the functionals a restricted GP is conditioned on
 * (restricted_gp.stan): diag(w) * df/dtheta at the quadrature nodes for the
 * orthogonal GP, the identity over the N physical points for the scaled GP.
 *
 * @param orthogonal 1 = orthogonal GP, 0 = scaled GP
 * @param X_quad quadrature nodes on the input box, original units
 * @param w_quad quadrature weights, summing to 1
 * @param theta calibration parameters, original units
 * @param theta_lower lower bounds of theta, original units
 * @param theta_upper upper bounds of theta, original units
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @param N the number of physical points
 * @return A, U x functionals (R x Q orthogonal, N x N scaled)
 */
matrix restriction_map(int orthogonal, matrix X_quad, vector w_quad, vector theta,
                       vector theta_lower, vector theta_upper, real y_center, real y_scale,
                       int N) {
  if (orthogonal) {
    return diag_pre_multiply(w_quad, simulator_theta_derivatives(X_quad, theta, theta_lower, theta_upper,
                                                        y_center, y_scale));
  }
  return identity_matrix(N);
}

/**
 * The user's simulator at points that may each have their own theta,
 * standardised like y: one call when theta is shared (one row), one call
 * per point otherwise.
 *
 * @param X inputs, one row per point, original units
 * @param theta_rows theta per point, original units (one row: shared by all points)
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return the standardised simulator, one value per row of X
 */
vector simulator_at_rows(matrix X, matrix theta_rows, real y_center, real y_scale) {
  if (rows(theta_rows) == 1) {
    return standardized_simulator(X, theta_rows[1]', y_center, y_scale);
  }
  vector[rows(X)] f;
  for (i in 1:rows(X)) {
    f[i] = standardized_simulator(X[i:i, :], theta_rows[i]', y_center, y_scale)[1];
  }
  return f;
}
