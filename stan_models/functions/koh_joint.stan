/**
 * Covariance of the stacked vector [y_sim; y_obs] in the joint KOH model
 * (Kennedy & O'Hagan 2001; review section 4.2): simulator runs and
 * physical data share one emulator GP over (x, theta); the physical block
 * adds the discrepancy GP and measurement noise. The runs may come from
 * simulators of several fidelities (fidelity.stan); the physical points see
 * the top one.
 *
 * @param xt_sim emulator inputs of the runs, (x, theta) on the unit cube
 * @param w_sim the runs' weights on the levels' GPs (one column for one fidelity)
 * @param xt_obs emulator inputs of the physical points at the current theta
 * @param w_obs the physical points' weights at the top level, one row per point (fidelity.stan)
 * @param x_delta discrepancy inputs of the physical points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param level_sd each level's emulator GP marginal sd
 * @param level_length_scale each level's emulator GP length scales
 * @param run_own_cov the runs' own covariance beside the kernel (same_point.stan's run_own_cov): each
 *        run's nugget, shared by a stochastic simulator's replicates, and their intrinsic variance
 * @param rho KOH scale: zeta = rho * f + delta
 * @param delta_sd discrepancy GP hyperparameters
 * @param delta_length_scale discrepancy GP hyperparameters
 *        (empty arrays for no discrepancy)
 * @param noise_var each physical point's noise variance (noise.stan's weighted_noise_variance)
 * @param point_cov the emulator's misfit among the physical points: its nugget where two
 *        points are one (Higdon et al. 2008), times rho^2; zeros where the program has none
 * @return covariance matrix of size M + N, with the jitter (add_jitter) of the top level's widest variance
 */
matrix koh_joint_cov(array[] vector xt_sim, matrix w_sim, array[] vector xt_obs, matrix w_obs,
                     array[] vector x_delta, int kernel_id, array[] real level_sd,
                     array[,] real level_length_scale, matrix run_own_cov, real rho,
                     array[] real delta_sd, array[] real delta_length_scale, vector noise_var,
                     matrix point_cov) {
  int m = size(xt_sim);
  int n = size(xt_obs);
  matrix[m + n, m + n] K;
  K[1:m, 1:m] = fidelity_cov(xt_sim, w_sim, kernel_id, level_sd, level_length_scale) + run_own_cov;
  K[1:m, (m + 1):(m + n)] = rho * fidelity_cross_cov(xt_sim, w_sim, xt_obs, w_obs, kernel_id, level_sd,
                                                     level_length_scale);
  K[(m + 1):(m + n), 1:m] = K[1:m, (m + 1):(m + n)]';
  matrix[n, n] K_obs = square(rho) * fidelity_cov(xt_obs, w_obs, kernel_id, level_sd, level_length_scale)
                       + point_cov;
  if (size(delta_sd) > 0) {
    K_obs += ard_cov(x_delta, kernel_id, delta_sd[1], delta_length_scale);
  }
  K[(m + 1):(m + n), (m + 1):(m + n)] = add_diag(K_obs, noise_var);
  return add_jitter(K, fidelity_variance(fidelity_widest(w_obs, level_sd), level_sd));
}

/**
 * koh_joint_cov with every physical point at the same weights w_top (constant scales), each run's
 * own sd on its own (run_nugget_sd), and no emulator misfit at the physical points.
 */
matrix koh_joint_cov(array[] vector xt_sim, matrix w_sim, array[] vector xt_obs, row_vector w_top,
                     array[] vector x_delta, int kernel_id, array[] real level_sd,
                     array[,] real level_length_scale, vector run_nugget_sd, real rho,
                     array[] real delta_sd, array[] real delta_length_scale, vector noise_var) {
  return koh_joint_cov(xt_sim, w_sim, xt_obs, rep_matrix(w_top, size(xt_obs)), x_delta, kernel_id, level_sd,
                       level_length_scale, diag_matrix(square(run_nugget_sd)), rho, delta_sd, delta_length_scale,
                       noise_var, rep_matrix(0, size(xt_obs), size(xt_obs)));
}

/**
 * The covariances of the emulated simulator f and the discrepancy delta at
 * new points, stacked [f_new; delta_new], for the joint KOH model: with the
 * rows [y_sim; y_obs], and among themselves (their prior covariance). f at a
 * point is the emulator's smooth GP plus its misfit there (point_nugget_var,
 * one value at one point, as at the physical points: Higdon et al. 2008), so
 * a new point where a physical point is shares that point's misfit.
 *
 * @param xt_sim as in koh_joint_cov
 * @param xt_obs as in koh_joint_cov
 * @param x_delta discrepancy inputs of the physical points
 * @param xt_new emulator inputs of the new points at the current theta
 * @param x_delta_new discrepancy inputs of the new points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param w_sim the runs' weights on the levels' GPs (fidelity.stan)
 * @param w_obs the physical points' weights at the top level, one row per point
 * @param w_new the new points' weights at the top level, one row per point
 * @param level_sd each level's emulator GP marginal sd
 * @param level_length_scale each level's emulator GP length scales: inputs first, then theta
 * @param rho the Kennedy-O'Hagan scale on the simulator
 * @param delta_sd the discrepancy GP's marginal sd (an empty array: no discrepancy)
 * @param delta_length_scale the discrepancy GP's length scales, one per discrepancy input
 * @param point_nugget_var the top level's nugget variance at the physical and new points (0: none)
 * @return (covariance with the rows, 2P x (M + N); prior covariance, 2P x 2P)
 */
tuple(matrix, matrix) koh_joint_new_cov(array[] vector xt_sim, array[] vector xt_obs, array[] vector x_delta,
                                        array[] vector xt_new, array[] vector x_delta_new, int kernel_id,
                                        matrix w_sim, matrix w_obs, matrix w_new, array[] real level_sd,
                                        array[,] real level_length_scale, real rho, array[] real delta_sd,
                                        array[] real delta_length_scale, real point_nugget_var) {
  int m = size(xt_sim);
  int n = size(xt_obs);
  int p = size(xt_new);
  matrix[2 * p, m + n] K_cross = rep_matrix(0, 2 * p, m + n);
  matrix[2 * p, 2 * p] K_new = rep_matrix(0, 2 * p, 2 * p);
  K_cross[1:p, 1:m] = fidelity_cross_cov(xt_new, w_new, xt_sim, w_sim, kernel_id, level_sd,
                                         level_length_scale);
  K_cross[1:p, (m + 1):(m + n)] = rho * (fidelity_cross_cov(xt_new, w_new, xt_obs, w_obs, kernel_id,
                                                            level_sd, level_length_scale)
                                         + point_nugget_var * same_point(xt_new, xt_obs));
  K_new[1:p, 1:p] = fidelity_cov(xt_new, w_new, kernel_id, level_sd, level_length_scale)
                    + point_nugget_var * same_point(xt_new);
  if (size(delta_sd) > 0) {
    K_cross[(p + 1):(2 * p), (m + 1):(m + n)]
      = ard_cross_cov(x_delta_new, x_delta, kernel_id, delta_sd[1], delta_length_scale);
    K_new[(p + 1):(2 * p), (p + 1):(2 * p)]
      = ard_cov(x_delta_new, kernel_id, delta_sd[1], delta_length_scale);
  }
  return (K_cross, K_new);
}

/**
 * One joint draw of the emulated simulator f and the discrepancy delta at
 * new points, given runs and physical data, for the joint KOH model, from
 * given standard normals.
 *
 * @param resid [y_sim; y_obs] minus their prior means
 * @param L_joint Cholesky factor of koh_joint_cov(...)
 * @param z standard normals, size 2P: f's, then delta's
 * @param other parameters as in koh_joint_new_cov
 * @return [f_new; delta_new] minus their prior means, size 2P
 */
vector koh_joint_predict(vector resid, matrix L_joint, array[] vector xt_sim,
                         array[] vector xt_obs, array[] vector x_delta,
                         array[] vector xt_new, array[] vector x_delta_new,
                         int kernel_id, matrix w_sim, matrix w_obs, matrix w_new, array[] real level_sd,
                         array[,] real level_length_scale, real rho,
                         array[] real delta_sd, array[] real delta_length_scale, vector z) {
  tuple(matrix[2 * size(xt_new), size(resid)], matrix[2 * size(xt_new), 2 * size(xt_new)]) K
    = koh_joint_new_cov(xt_sim, xt_obs, x_delta, xt_new, x_delta_new, kernel_id, w_sim, w_obs, w_new, level_sd,
                        level_length_scale, rho, delta_sd, delta_length_scale, 0);
  return gp_conditional_draw(resid, L_joint, K.1, K.2, z);
}

/**
 * koh_joint_predict with every physical and new point at the same weights w_top (constant scales).
 */
vector koh_joint_predict(vector resid, matrix L_joint, array[] vector xt_sim,
                         array[] vector xt_obs, array[] vector x_delta,
                         array[] vector xt_new, array[] vector x_delta_new,
                         int kernel_id, matrix w_sim, row_vector w_top, array[] real level_sd,
                         array[,] real level_length_scale, real rho,
                         array[] real delta_sd, array[] real delta_length_scale, vector z) {
  return koh_joint_predict(resid, L_joint, xt_sim, xt_obs, x_delta, xt_new, x_delta_new, kernel_id, w_sim,
                           rep_matrix(w_top, size(xt_obs)), rep_matrix(w_top, size(xt_new)), level_sd,
                           level_length_scale, rho, delta_sd, delta_length_scale, z);
}

/**
 * One posterior draw of the emulated simulator f and the discrepancy delta
 * at the given points, for the emulator-based KOH programs, jointly with any
 * other GP terms the physical rows see (the measurement biases,
 * source_bias.stan): given the data they are correlated with f and delta, so
 * only a joint draw gives a sum of them its spread. Under prior_only the draw
 * conditions on the runs alone: the leading M x M block of L_joint is the
 * Cholesky factor of the runs' covariance (the other terms are then drawn
 * from their prior).
 *
 * @param resid [y_sim; y_obs] minus their prior means
 * @param L_joint Cholesky factor of koh_joint_cov(...)
 * @param prior_only 1 = ignore the physical data
 * @param xt_sim emulator inputs of the runs
 * @param xt_obs emulator inputs (x, theta on the unit cube) of the physical points
 * @param x_delta discrepancy inputs of the physical points
 * @param xt_new emulator inputs of the prediction points
 * @param x_delta_new discrepancy inputs of the prediction points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param w_sim, w_obs, w_new, level_sd, level_length_scale the emulator, as in koh_joint_predict
 * @param rho the Kennedy-O'Hagan scale on the simulator
 * @param delta_sd the discrepancy GP's marginal sd (an empty array: no discrepancy)
 * @param delta_length_scale the discrepancy GP's length scales, one per discrepancy input
 * @param point_nugget_var the top level's nugget variance at the points, part of f there (koh_joint_new_cov)
 * @param other_cross the other terms' values' covariance with the physical rows y_obs (0 rows: none)
 * @param other_new their prior covariance (independent of f and delta a priori)
 * @param z standard normals: one per new point for f, one per new point for delta, then one per
 *        other value
 * @return [f minus its prior mean; delta; the other terms' values], 2P + rows(other_new)
 */
vector koh_joint_draw(vector resid, matrix L_joint, int prior_only,
                      array[] vector xt_sim, array[] vector xt_obs,
                      array[] vector x_delta, array[] vector xt_new,
                      array[] vector x_delta_new, int kernel_id, matrix w_sim, matrix w_obs, matrix w_new,
                      array[] real level_sd, array[,] real level_length_scale, real rho,
                      array[] real delta_sd, array[] real delta_length_scale, real point_nugget_var,
                      matrix other_cross, matrix other_new, vector z) {
  int m = size(xt_sim);
  int n_cond = prior_only ? 0 : size(xt_obs);
  int p = size(xt_new);
  int k = 2 * p + rows(other_new);
  if (k == 0) return rep_vector(0, 0);
  // covariances with [y_sim; y_obs] and among the values: f and delta's, then the other terms',
  // which see the physical rows only, and are independent of f and delta a priori
  matrix[k, m + n_cond] K_cross = rep_matrix(0, k, m + n_cond);
  matrix[k, k] K_new = rep_matrix(0, k, k);
  if (p > 0) {
    tuple(matrix[2 * p, m + n_cond], matrix[2 * p, 2 * p]) f_delta = koh_joint_new_cov(
      xt_sim, xt_obs[1:n_cond], x_delta[1:n_cond], xt_new, x_delta_new, kernel_id, w_sim, w_obs[1:n_cond], w_new,
      level_sd, level_length_scale, rho, delta_sd, delta_length_scale, point_nugget_var);
    K_cross[1:(2 * p)] = f_delta.1;
    K_new[1:(2 * p), 1:(2 * p)] = f_delta.2;
  }
  K_cross[(2 * p + 1):k, (m + 1):(m + n_cond)] = other_cross[:, 1:n_cond];
  K_new[(2 * p + 1):k, (2 * p + 1):k] = other_new;
  return gp_conditional_draw(resid[1:(m + n_cond)], L_joint[1:(m + n_cond), 1:(m + n_cond)], K_cross, K_new, z);
}

/**
 * The generated quantities that the emulator-based Gaussian programs
 * (koh_emulator.stan, modular.stan) share: with the emulator's
 * hyperparameters given, the joint model's conditionals are exact. f, delta
 * and the measurement biases (source_bias.stan) are drawn jointly, at the
 * physical points (y_rep: a posterior predictive check) and at the
 * prediction points (predict()'s new readings by a biased source, zeta + b_s).
 * f at a point includes the emulator's misfit there (point_nugget_var): y_rep
 * conditions on the misfit the data condition on, as on f, delta and the
 * biases, and draws only the noise afresh. A replicated experiment reads the
 * same process through the same simulator at the same theta: the simulator's
 * value there, misfit included, is one quantity, whose posterior the data
 * inform (Gelman, Meng & Stern 1996: replicate the data, keep the latent
 * quantities). At new points f_new carries the misfit too (koh_joint_new_cov).
 *
 * @param y_sim standardised outputs of the runs and of the physical points
 * @param y standardised outputs of the runs and of the physical points
 * @param xt_sim emulator inputs of the runs
 * @param x simulator and discrepancy inputs of the physical points
 * @param x_delta simulator and discrepancy inputs of the physical points
 * @param h discrepancy mean terms at the physical points and their coefficients
 * @param beta discrepancy mean terms at the physical points and their coefficients
 * @param x_new the same at the prediction points
 * @param x_delta_new the same at the prediction points
 * @param h_new the same at the prediction points
 * @param normals_new standard normals for the draws at the prediction points
 *        (prediction_normals_rng): column 1 for f, column 2 for delta
 * @param other parameters as in koh_joint_cov; y_center, y_scale as in the programs
 * @param theta_unit every theta on [0, 1]; a functional theta's level
 * @param prior_only 1 = draws from the prior (the data ignored)
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param w_sim the runs' weights on the levels' GPs (fidelity.stan; one column for one fidelity)
 * @param w_obs the physical points' weights at the top level, one row per point
 * @param w_new the prediction points' weights at the top level, one row per point
 * @param level_mean each level's emulator GP constant mean
 * @param level_sd each level's emulator GP marginal sd
 * @param level_length_scale each level's GP length scales: inputs first, then theta
 * @param run_own_cov the runs' own covariance beside the kernel, as in koh_joint_cov
 * @param rho the Kennedy-O'Hagan scale on the simulator
 * @param delta_sd the discrepancy GP's marginal sd (an empty array: no discrepancy)
 * @param delta_length_scale the discrepancy GP's length scales, one per discrepancy input
 * @param noise_var each point's noise variance, given the Student-t mixture weights where there are
 *        some (noise.stan's weighted_noise_variance), standardised units
 * @param point_nugget_var the top level's nugget variance, the emulator's misfit at a point (0: none):
 *        rho^2 point_nugget_var where two physical points are one (koh_joint_cov's point_cov)
 * @param bias the measurement biases (source_bias.stan's source_bias_blocks): their covariance among
 *        the physical points (0 x 0: no biased source), their values' at the prediction points
 *        covariance with the physical points, and those values' prior covariance
 * @param z_bias standard normals for the biases at the prediction points (source_bias_normals_rng)
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return (log_lik, y_loo_mean, y_rep, delta_gp, delta_gp_mean at the physical
 *         points; f_new, delta_new, zeta_new at the prediction points; the biases there, stacked
 *         as source_bias_blocks stacks them), original units
 */
tuple(vector, vector, vector, vector, vector, vector, vector, vector, vector) koh_joint_quantities_rng(
    vector y_sim, vector y, array[] vector xt_sim, array[] vector x, vector theta_unit,
    array[] vector x_delta, matrix h, vector beta, array[] vector x_new,
    array[] vector x_delta_new, matrix h_new, matrix normals_new, int prior_only,
    int kernel_id, matrix w_sim, matrix w_obs, matrix w_new, array[] real level_mean, array[] real level_sd,
    array[,] real level_length_scale, matrix run_own_cov, real rho, array[] real delta_sd,
    array[] real delta_length_scale, vector noise_var, real point_nugget_var, tuple(matrix, matrix, matrix) bias,
    vector z_bias, real y_center, real y_scale) {
  int m = size(xt_sim);
  int n = size(x);
  int p = size(x_new);
  int n_b = rows(bias.1);  // the biases at the physical points: n of them, or none
  matrix[n, n] bias_cov = n_b > 0 ? bias.1 : rep_matrix(0, n, n);
  array[n] vector[num_elements(xt_sim[1])] xt_obs = append_theta(x, theta_unit);
  matrix[n, n] point_cov = square(rho) * point_nugget_var * same_point(x);
  matrix[m + n, m + n] L = cholesky_decompose(
    koh_joint_cov(xt_sim, w_sim, xt_obs, w_obs, x_delta, kernel_id, level_sd, level_length_scale,
                  run_own_cov, rho, delta_sd, delta_length_scale, noise_var, point_cov + bias_cov));
  vector[n] top_mean = w_obs * to_vector(level_mean);  // the top level's prior mean at each point
  vector[m + n] resid = append_row(y_sim, y) - append_row(w_sim * to_vector(level_mean),
                                                          rho * top_mean + h * beta);
  tuple(vector[m + n], vector[m + n]) loo = mvn_loo(resid, L);
  // (f, delta, the biases) at the physical points, then at the prediction points, whose
  // standard normals stancal may give
  vector[2 * n + n_b] at_obs = koh_joint_draw(
    resid, L, prior_only, xt_sim, xt_obs, x_delta, xt_obs, x_delta, kernel_id, w_sim, w_obs, w_obs, level_sd,
    level_length_scale, rho, delta_sd, delta_length_scale, point_nugget_var, bias_cov[1:n_b], bias.1,
    std_normals_rng(2 * n + n_b));
  // f's normals, then delta's, each in a statement of its own: C++ leaves the order in which
  // one expression's arguments are evaluated open, so two draws in one call could swap
  vector[p] z_f_new = prediction_normals_rng(normals_new, 1, p);
  vector[p] z_delta_new = prediction_normals_rng(normals_new, 2, p);
  vector[2 * p + rows(bias.3)] at_new = koh_joint_draw(
    resid, L, prior_only, xt_sim, xt_obs, x_delta, append_theta(x_new, theta_unit), x_delta_new,
    kernel_id, w_sim, w_obs, w_new, level_sd, level_length_scale, rho, delta_sd, delta_length_scale,
    point_nugget_var, bias.2, bias.3, append_row(z_f_new, append_row(z_delta_new, z_bias)));
  vector[n] zeta_obs = rho * (top_mean + at_obs[1:n]) + h * beta + at_obs[(n + 1):(2 * n)];
  vector[p] f_new = w_new * to_vector(level_mean) + at_new[1:p];
  vector[p] delta_new = h_new * beta + at_new[(p + 1):(2 * p)];
  vector[n] delta_gp_mean = rep_vector(0, n);
  if (size(delta_sd) > 0 && !prior_only) {
    delta_gp_mean = gp_conditional_mean(resid, L, append_col(
      rep_matrix(0, n, m), ard_cov(x_delta, kernel_id, delta_sd[1], delta_length_scale)));
  }
  return (loo.1[(m + 1):(m + n)] - log(y_scale),
          y_center + y_scale * (y - resid[(m + 1):(m + n)] + loo.2[(m + 1):(m + n)]),
          y_center + y_scale * to_vector(normal_rng(
            zeta_obs + (n_b > 0 ? at_obs[(2 * n + 1):(2 * n + n_b)] : rep_vector(0, n)), sqrt(noise_var))),
          y_scale * at_obs[(n + 1):(2 * n)],
          y_scale * delta_gp_mean,
          y_center + y_scale * f_new,
          y_scale * delta_new,
          y_center + y_scale * (rho * f_new + delta_new),
          y_scale * at_new[(2 * p + 1):(2 * p + rows(bias.3))]);
}
