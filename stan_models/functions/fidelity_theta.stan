/**
 * The cheapest level's own calibration parameters theta_l (Goh et al. 2013,
 * Technometrics 55(4); review section 8.3): the calibrated simulator is
 *   f_top(x, theta) = rho f_1(x, theta_l) + g_2(x, theta),
 * the cheap simulator at its own best setting theta_l plus the expensive
 * one's GP over (x, theta). Every point lives in (x, theta, theta_l) on
 * the unit cube; each level's GP ignores the parameters that are not its own
 * (stage 1 gives them a length scale so long that their kernel factor is
 * exactly 1: stancal.numerics.multifidelity_theta). The runs above the
 * cheapest level are runs of a simulator without theta_l: their cheap part
 * is the cheap simulator at the same best theta_l as the physical data's, so
 * their theta_l coordinates are the parameter, and their covariance with
 * the cheap runs moves with it.
 */

/**
 * The runs' (x, theta, theta_l) at a value of theta_l: the cheap runs keep
 * their own theta_l, the runs above take the parameter.
 *
 * @param x_sim the runs' simulator inputs on the unit cube
 * @param theta_sim the runs' (theta, theta_l) on the unit cube
 * @param run_level each run's level (1 = the cheapest)
 * @param theta_low_unit theta_l on the unit cube, size Q_low
 * @return the runs' kernel inputs, size(x_sim) points of size D + Q + Q_low
 */
array[] vector runs_at_theta_low(array[] vector x_sim, array[] vector theta_sim, array[] int run_level,
                                 vector theta_low_unit) {
  int m = size(x_sim);
  int q_all = num_elements(theta_sim[1]);
  int q_low = num_elements(theta_low_unit);
  array[m] vector[num_elements(x_sim[1]) + q_all] xt;
  for (j in 1:m) {
    vector[q_all] theta_j = theta_sim[j];
    if (run_level[j] > 1) theta_j[(q_all - q_low + 1):q_all] = theta_low_unit;
    xt[j] = append_row(x_sim[j], theta_j);
  }
  return xt;
}

/**
 * The emulator of the top level at the physical points given the runs:
 * its mean and covariance (the usual kriging formulas on the runs' factor).
 *
 * @param K_obs_run covariance of the points with the runs
 * @param L_run Cholesky factor of the runs' covariance
 * @param alpha_run K_run^-1 (y_sim - mean)
 * @param top_mean the top level's prior mean at each point
 * @param K_obs the points' prior covariance
 * @return (mean, covariance) at the points
 */
tuple(vector, matrix) fidelity_at_points(matrix K_obs_run, matrix L_run, vector alpha_run, vector top_mean,
                                         matrix K_obs) {
  matrix[cols(K_obs_run), rows(K_obs_run)] A = mdivide_left_tri_low(L_run, K_obs_run');
  return (top_mean + K_obs_run * alpha_run, K_obs - crossprod(A));
}

/**
 * The physical points' covariance with the runs at (theta, theta_l).
 * Squared exponential: level by level, the x factor (data) times the
 * parameters' factor; else the kernel over every input.
 *
 * @param K_obs_sim_x each level's x factor times the weights, N x M
 * @param x the physical points' simulator inputs on the unit cube
 * @param theta_all (theta, theta_l) on the unit cube
 * @param xt_run the runs' kernel inputs, (x, theta, theta_l)
 * @param w_obs, w_sim the points' and the runs' weights on the levels' GPs
 * @return N x M covariance
 */
matrix fidelity_points_runs_cov(array[] matrix K_obs_sim_x, array[] vector x, vector theta_all,
                                array[] vector xt_run, matrix w_obs, matrix w_sim, int kernel_id,
                                array[] real level_sd, array[,] real level_length_scale) {
  int D = num_elements(x[1]);
  int q = num_elements(theta_all);
  int m = size(xt_run);
  if (kernel_id != 1) {
    return fidelity_cross_cov(append_theta(x, theta_all), w_obs, xt_run, w_sim, kernel_id, level_sd,
                              level_length_scale);
  }
  array[m] vector[q] theta_run;
  for (j in 1:m) theta_run[j] = xt_run[j][(D + 1):(D + q)];
  matrix[size(x), m] K = diag_post_multiply(K_obs_sim_x[1], theta_factor(theta_all, theta_run,
                                                                          level_length_scale[1, (D + 1):(D + q)]));
  for (j in 2:size(level_sd)) {
    K += diag_post_multiply(K_obs_sim_x[j], theta_factor(theta_all, theta_run, level_length_scale[j, (D + 1):(D + q)]));
  }
  return K;
}
