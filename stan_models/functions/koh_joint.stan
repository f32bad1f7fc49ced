/**
 * Covariance of the stacked vector [y_sim; y_obs] in the joint KOH model
 * (Kennedy & O'Hagan 2001; review section 4.2): simulator runs and
 * physical data share one emulator GP over (x, theta); the physical block
 * adds the discrepancy GP and measurement noise.
 *
 * @param xt_sim emulator inputs of the runs, (x, theta) on the unit cube
 * @param xt_obs emulator inputs of the physical points at the current theta
 * @param x_delta discrepancy inputs of the physical points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param emulator_sd, emulator_length_scale emulator GP hyperparameters
 * @param emulator_nugget standard deviation of the runs' jitter
 * @param rho KOH scale: zeta = rho * f + delta
 * @param delta_sd, delta_length_scale discrepancy GP hyperparameters
 *        (empty arrays for no discrepancy)
 * @param noise_sd measurement noise standard deviation
 * @return covariance matrix of size M + N
 */
matrix koh_joint_cov(array[] vector xt_sim, array[] vector xt_obs,
                     array[] vector x_delta, int kernel_id,
                     real emulator_sd, array[] real emulator_length_scale,
                     real emulator_nugget, real rho, array[] real delta_sd,
                     array[] real delta_length_scale, real noise_sd) {
  int m = size(xt_sim);
  int n = size(xt_obs);
  matrix[m + n, m + n] K;
  K[1:m, 1:m] = add_diag(ard_cov(xt_sim, kernel_id, emulator_sd, emulator_length_scale),
                         square(emulator_nugget));
  K[1:m, (m + 1):(m + n)] = rho * ard_cross_cov(xt_sim, xt_obs, kernel_id, emulator_sd,
                                                emulator_length_scale);
  K[(m + 1):(m + n), 1:m] = K[1:m, (m + 1):(m + n)]';
  matrix[n, n] K_obs = square(rho) * ard_cov(xt_obs, kernel_id, emulator_sd,
                                             emulator_length_scale);
  if (size(delta_sd) > 0) {
    K_obs += ard_cov(x_delta, kernel_id, delta_sd[1], delta_length_scale);
  }
  K[(m + 1):(m + n), (m + 1):(m + n)] = add_diag(K_obs, square(noise_sd));
  return K;
}

/**
 * One joint draw of the emulated simulator f and the discrepancy delta at
 * new points, given runs and physical data, for the joint KOH model.
 *
 * @param resid [y_sim; y_obs] minus their prior means
 * @param L_joint Cholesky factor of koh_joint_cov(...)
 * @param xt_sim, xt_obs as in koh_joint_cov
 * @param x_delta discrepancy inputs of the physical points
 * @param xt_new emulator inputs of the new points at the current theta
 * @param x_delta_new discrepancy inputs of the new points
 * @param other parameters as in koh_joint_cov
 * @return [f_new; delta_new] minus their prior means, size 2P
 */
vector koh_joint_predict_rng(vector resid, matrix L_joint, array[] vector xt_sim,
                             array[] vector xt_obs, array[] vector x_delta,
                             array[] vector xt_new, array[] vector x_delta_new,
                             int kernel_id, real emulator_sd,
                             array[] real emulator_length_scale, real rho,
                             array[] real delta_sd, array[] real delta_length_scale) {
  int m = size(xt_sim);
  int n = size(xt_obs);
  int p = size(xt_new);
  matrix[2 * p, m + n] K_cross = rep_matrix(0, 2 * p, m + n);
  matrix[2 * p, 2 * p] K_new = rep_matrix(0, 2 * p, 2 * p);
  K_cross[1:p, 1:m] = ard_cross_cov(xt_new, xt_sim, kernel_id, emulator_sd,
                                    emulator_length_scale);
  K_cross[1:p, (m + 1):(m + n)] = rho * ard_cross_cov(xt_new, xt_obs, kernel_id,
                                                      emulator_sd, emulator_length_scale);
  K_new[1:p, 1:p] = ard_cov(xt_new, kernel_id, emulator_sd, emulator_length_scale);
  if (size(delta_sd) > 0) {
    K_cross[(p + 1):(2 * p), (m + 1):(m + n)]
      = ard_cross_cov(x_delta_new, x_delta, kernel_id, delta_sd[1], delta_length_scale);
    K_new[(p + 1):(2 * p), (p + 1):(2 * p)]
      = ard_cov(x_delta_new, kernel_id, delta_sd[1], delta_length_scale);
  }
  return gp_conditional_rng(resid, L_joint, K_cross, K_new);
}

/**
 * One posterior draw of the emulated simulator f and the discrepancy delta
 * at the given points, for the emulator-based KOH programs. Under
 * prior_only the draw conditions on the runs alone: the leading M x M block
 * of L_joint is the Cholesky factor of the runs' covariance.
 *
 * @param resid [y_sim; y_obs] minus their prior means
 * @param L_joint Cholesky factor of koh_joint_cov(...)
 * @param prior_only 1 = ignore the physical data
 * @param xt_sim, xt_obs, x_delta, xt_new, x_delta_new, other parameters
 *        as in koh_joint_predict_rng
 * @return matrix with one row per new point: column 1 = f minus its prior
 *         mean, column 2 = delta
 */
matrix koh_joint_draw_rng(vector resid, matrix L_joint, int prior_only,
                          array[] vector xt_sim, array[] vector xt_obs,
                          array[] vector x_delta, array[] vector xt_new,
                          array[] vector x_delta_new, int kernel_id, real emulator_sd,
                          array[] real emulator_length_scale, real rho,
                          array[] real delta_sd, array[] real delta_length_scale) {
  int m = size(xt_sim);
  int n_cond = prior_only ? 0 : size(xt_obs);
  int p = size(xt_new);
  vector[2 * p] f_delta = koh_joint_predict_rng(
    resid[1:(m + n_cond)], L_joint[1:(m + n_cond), 1:(m + n_cond)], xt_sim,
    xt_obs[1:n_cond], x_delta[1:n_cond], xt_new, x_delta_new, kernel_id, emulator_sd,
    emulator_length_scale, rho, delta_sd, delta_length_scale);
  return append_col(f_delta[1:p], f_delta[(p + 1):(2 * p)]);
}
