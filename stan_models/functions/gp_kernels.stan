/**
 * Stationary ARD covariance between two sets of points.
 *
 * Inputs are expected on the unit cube, so length scales are fractions of
 * each input's range.
 *
 * @param x1 first set of points
 * @param x2 second set of points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 *        (mirrored in Python by stancal.models.Kernel)
 * @param marginal_sd marginal standard deviation of the process
 * @param length_scale one length scale per input dimension
 * @return covariance matrix, size(x1) x size(x2)
 */
matrix ard_cross_cov(array[] vector x1, array[] vector x2, int kernel_id,
                     real marginal_sd, array[] real length_scale) {
  if (kernel_id == 2) {
    return gp_matern52_cov(x1, x2, marginal_sd, length_scale);
  }
  return gp_exp_quad_cov(x1, x2, marginal_sd, length_scale);
}

/**
 * Stationary ARD covariance of one set of points with itself.
 * The symmetric built-ins are used because they have faster gradients.
 *
 * @param x points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd marginal standard deviation of the process
 * @param length_scale one length scale per input dimension
 * @return covariance matrix, size(x) x size(x)
 */
matrix ard_cov(array[] vector x, int kernel_id, real marginal_sd,
               array[] real length_scale) {
  if (kernel_id == 2) {
    return gp_matern52_cov(x, marginal_sd, length_scale);
  }
  return gp_exp_quad_cov(x, marginal_sd, length_scale);
}

/**
 * Points whose coordinates are the given inputs followed by one shared
 * parameter vector: the emulator's (x, theta) inputs at a fixed theta.
 *
 * @param x input points, each of size D
 * @param theta_unit calibration parameters on the unit cube, size Q
 * @return points of size D + Q
 */
array[] vector append_theta(array[] vector x, vector theta_unit) {
  int n = size(x);
  array[n] vector[n > 0 ? num_elements(x[1]) + num_elements(theta_unit) : 0] xt;
  for (i in 1:n) {
    xt[i] = append_row(x[i], theta_unit);
  }
  return xt;
}
