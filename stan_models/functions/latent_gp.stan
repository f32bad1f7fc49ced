/**
 * Latent GPs in the non-centred parameterisation, for the programs whose
 * likelihood does not let the GP be integrated out (koh_latent*.stan):
 * values = L z, z ~ N(0, I), L the Cholesky factor of the covariance.
 */

/**
 * Cholesky factor of a latent GP's covariance at the points. A relative
 * jitter of 1e-6 keeps it positive definite where points repeat.
 */
matrix latent_gp_cholesky(array[] vector x, int kernel_id, real marginal_sd,
                          array[] real length_scale) {
  return cholesky_decompose(add_diag(ard_cov(x, kernel_id, marginal_sd, length_scale),
                                     1e-6 * square(marginal_sd)));
}

/**
 * GP values at the points from standard normals z.
 */
vector latent_gp(array[] vector x, int kernel_id, real marginal_sd,
                 array[] real length_scale, vector z) {
  return latent_gp_cholesky(x, kernel_id, marginal_sd, length_scale) * z;
}

/**
 * One draw of a latent GP at new points given its values at the points.
 */
vector latent_gp_predict_rng(vector values, array[] vector x, array[] vector x_new,
                             int kernel_id, real marginal_sd, array[] real length_scale) {
  return gp_conditional_rng(values, latent_gp_cholesky(x, kernel_id, marginal_sd, length_scale),
                            ard_cross_cov(x_new, x, kernel_id, marginal_sd, length_scale),
                            ard_cov(x_new, kernel_id, marginal_sd, length_scale));
}

/**
 * The emulated simulator at the physical points given the runs, as a latent
 * draw: f = mean + K_os K_ss^-1 (y_sim - mean) + chol(K_oo - K_os K_ss^-1 K_so) z.
 * The runs carry the nugget; f at the physical points does not.
 *
 * @param L_sim Cholesky factor of the runs' covariance, nugget included
 * @param xt_sim, y_sim emulator inputs (x, theta on the unit cube) and standardised outputs of the runs
 * @param xt_obs emulator inputs of the physical points at their theta
 * @param z standard normals, one per physical point
 * @return f at the physical points, standardised like y_sim
 */
vector emulator_latent(matrix L_sim, array[] vector xt_sim, vector y_sim, array[] vector xt_obs,
                       int kernel_id, real emulator_mean, real emulator_sd,
                       array[] real emulator_length_scale, vector z) {
  int n = size(xt_obs);
  matrix[size(xt_sim), n] A = mdivide_left_tri_low(
    L_sim, ard_cross_cov(xt_sim, xt_obs, kernel_id, emulator_sd, emulator_length_scale));
  vector[n] mean_obs = emulator_mean + A' * mdivide_left_tri_low(L_sim, y_sim - emulator_mean);
  matrix[n, n] cov_obs = ard_cov(xt_obs, kernel_id, emulator_sd, emulator_length_scale) - crossprod(A);
  // symmetrise against round-off; the jitter as in latent_gp_cholesky
  return mean_obs + cholesky_decompose(add_diag(0.5 * (cov_obs + cov_obs'), 1e-6 * square(emulator_sd))) * z;
}
