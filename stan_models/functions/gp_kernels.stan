/**
 * The one jitter policy of stancal's programs: every covariance that is
 * factorised gets 1e-6 of its prior variance on the diagonal. That keeps the
 * Cholesky factorisation positive definite where points repeat, where a
 * stage-1 nugget vanishes, or where a conditional is nearly exact, and it is
 * far below anything the data can resolve (an sd of 0.1 % of the GP's).
 *
 * @param K covariance matrix
 * @param prior_variance the variance of the process before any conditioning
 *        (e.g. marginal_sd^2)
 * @return K with the jitter on its diagonal
 */
matrix add_jitter(matrix K, real prior_variance) {
  return add_diag(K, 1e-6 * prior_variance);
}

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
 * The discrepancy's ARD length scales over all its inputs: the simulator
 * inputs' own, then 1 / relevance for each covariate (covariate_relevance
 * in priors.stan). The sampler keeps a relevance above 0, so the length
 * scale stays finite, however long.
 *
 * @param input_length_scale one per simulator input
 * @param relevance one per covariate
 * @return length scales, simulator inputs first
 */
array[] real discrepancy_length_scales(array[] real input_length_scale, array[] real relevance) {
  return append_array(input_length_scale, inv(relevance));
}

/**
 * Covariance of the simulator runs under the emulator GP: the kernel over
 * (x, theta), the nugget, and the jitter.
 *
 * @param xt_sim emulator inputs of the runs, (x, theta) on the unit cube
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param emulator_sd emulator GP hyperparameters
 * @param emulator_length_scale emulator GP hyperparameters
 * @param emulator_nugget standard deviation of the runs' nugget
 * @return covariance matrix, size(xt_sim) x size(xt_sim)
 */
matrix emulator_run_cov(array[] vector xt_sim, int kernel_id, real emulator_sd,
                        array[] real emulator_length_scale, real emulator_nugget) {
  return add_jitter(add_diag(ard_cov(xt_sim, kernel_id, emulator_sd, emulator_length_scale),
                             square(emulator_nugget)), square(emulator_sd));
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

/**
 * The theta factor of the squared-exponential kernel over (x, theta)
 * between one theta and each run's theta: the kernel is the x factor times
 * exp(-0.5 sum_q ((theta_q - theta_jq) / l_q)^2). A program whose only
 * parameter among the kernel's inputs is theta keeps the x factor as data
 * (modular.stan).
 *
 * @param theta_unit theta on the unit cube
 * @param theta_sim the runs' theta on the unit cube
 * @param length_scale the emulator's theta length scales
 * @return one factor per run
 */
vector theta_factor(vector theta_unit, array[] vector theta_sim, array[] real length_scale) {
  int m = size(theta_sim);
  vector[num_elements(theta_unit)] inv_length_scale = inv(to_vector(length_scale));
  vector[m] factor;
  for (j in 1:m) factor[j] = exp(-0.5 * dot_self((theta_unit - theta_sim[j]) .* inv_length_scale));
  return factor;
}
