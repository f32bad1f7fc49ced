/**
 * Simulators of several fidelities, cheapest first (Kennedy & O'Hagan 2000;
 * review section 8.3): level 1 is a GP g_1 over (x, theta), and each level
 * above is a scale of the one below plus a GP of its own,
 *   f_1 = g_1,   f_k = level_rho[k - 1] * f_(k-1) + g_k,
 * with independent g_k. So f_k = sum_j w_kj g_j with w_kj the product of
 * the scales from level j up to level k (w_kk = 1, w_kj = 0 above k), and
 *   cov(f_a(s), f_b(t)) = sum_j w_aj w_bj k_j(s, t).
 * Each run carries its level's weights; the calibrated simulator is the top
 * level. With one level every weight is 1 and this is the usual emulator.
 * A scale may depend on the simulator's inputs, rho_k(x) = beta_0 + x' beta_x
 * (Le Gratiet & Garnier 2014, section 2): the weights are then each point's.
 */

/**
 * Each level's weights on the levels' GPs.
 *
 * @param level_rho scale of each level on the one below, size L - 1
 * @return L x L matrix: row k holds w_kj
 */
matrix fidelity_weights(vector level_rho) {
  int L = rows(level_rho) + 1;
  matrix[L, L] w = rep_matrix(0, L, L);
  for (k in 1:L) {
    w[k, k] = 1;
    for (j in 1:(k - 1)) w[k, j] = w[k - 1, j] * level_rho[k - 1];
  }
  return w;
}

/**
 * Each point's weights at its level with scales linear in the inputs,
 * rho_k(x) = level_rho[k - 1] + level_rho_slope[k - 1] * x (Le Gratiet &
 * Garnier 2014, section 2; zero slopes: constant scales).
 *
 * @param level_rho each level's scale on the one below at x = 0 (its intercept), size L - 1
 * @param level_rho_slope its slopes on the inputs, (L - 1) x D, unit-cube units
 * @param x the points' simulator inputs on the unit cube
 * @param level each point's level
 * @return size(x) x L matrix: row i holds w_kj(x_i), k point i's level
 */
matrix fidelity_point_weights(vector level_rho, matrix level_rho_slope, array[] vector x, array[] int level) {
  int L = rows(level_rho) + 1;
  matrix[size(x), L] w;
  for (i in 1:size(x)) w[i] = fidelity_weights(level_rho + level_rho_slope * x[i])[level[i], :];
  return w;
}

/**
 * The emulator's covariance between two sets of points at given levels.
 *
 * @param xt1 points (x, theta) on the unit cube
 * @param w1 their weights on the levels' GPs, size(xt1) x L (rows of fidelity_weights)
 * @param xt2 as xt1
 * @param w2 as w1
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param level_sd each level's GP marginal sd
 * @param level_length_scale each level's GP length scales, (x, theta)
 * @return covariance matrix, size(xt1) x size(xt2)
 */
matrix fidelity_cross_cov(array[] vector xt1, matrix w1, array[] vector xt2, matrix w2, int kernel_id,
                          array[] real level_sd, array[,] real level_length_scale) {
  if (size(level_sd) == 1) {  // one fidelity: every weight is 1
    return ard_cross_cov(xt1, xt2, kernel_id, level_sd[1], level_length_scale[1]);
  }
  matrix[size(xt1), size(xt2)] K = rep_matrix(0, size(xt1), size(xt2));
  for (j in 1:size(level_sd)) {
    K += diag_pre_multiply(col(w1, j), diag_post_multiply(
      ard_cross_cov(xt1, xt2, kernel_id, level_sd[j], level_length_scale[j]), col(w2, j)));
  }
  return K;
}

/**
 * The same covariance of one set of points with itself (the symmetric
 * kernels have faster gradients).
 */
matrix fidelity_cov(array[] vector xt, matrix w, int kernel_id, array[] real level_sd,
                    array[,] real level_length_scale) {
  if (size(level_sd) == 1) return ard_cov(xt, kernel_id, level_sd[1], level_length_scale[1]);
  matrix[size(xt), size(xt)] K = rep_matrix(0, size(xt), size(xt));
  for (j in 1:size(level_sd)) {
    K += quad_form_diag(ard_cov(xt, kernel_id, level_sd[j], level_length_scale[j]), col(w, j));
  }
  return K;
}

/**
 * The prior variance of the top level at a point: the scale of the jitter
 * (add_jitter) of every covariance that includes it.
 *
 * @param w_top the top level's weights
 * @param level_sd each level's GP marginal sd
 * @return sum_j (w_top_j sd_j)^2
 */
real fidelity_variance(row_vector w_top, array[] real level_sd) {
  return dot_self(w_top' .* to_vector(level_sd));
}

/**
 * The widest of some points' weights: the row whose prior variance
 * (fidelity_variance) is largest, the scale of the jitter (add_jitter).
 *
 * @param w the points' weights, one row per point
 * @param level_sd each level's GP marginal sd
 * @return one row of w
 */
row_vector fidelity_widest(matrix w, array[] real level_sd) {
  vector[rows(w)] variance;
  for (i in 1:rows(w)) variance[i] = fidelity_variance(w[i], level_sd);
  return w[sort_indices_desc(variance)[1]];
}

/**
 * The covariance of the runs of every level: the kernel, each run's nugget
 * (its level's) and the jitter (add_jitter) of the top level's variance.
 *
 * @param xt_sim the runs' (x, theta) on the unit cube
 * @param w_sim their weights on the levels' GPs
 * @param w_top the top level's weights (the jitter's scale)
 * @param run_nugget_sd each run's nugget sd
 * @return covariance matrix, size(xt_sim) x size(xt_sim)
 */
matrix fidelity_run_cov(array[] vector xt_sim, matrix w_sim, row_vector w_top, int kernel_id,
                        array[] real level_sd, array[,] real level_length_scale, vector run_nugget_sd) {
  return fidelity_run_cov(xt_sim, w_sim, w_top, kernel_id, level_sd, level_length_scale,
                          diag_matrix(square(run_nugget_sd)));
}

/**
 * fidelity_run_cov with the runs' own covariance given whole (same_point.stan's
 * run_own_cov: a stochastic simulator's replicates share their nugget).
 *
 * @param run_own_cov the runs' own covariance beside the kernel
 * @return covariance matrix of the runs, with the jitter
 */
matrix fidelity_run_cov(array[] vector xt_sim, matrix w_sim, row_vector w_top, int kernel_id,
                        array[] real level_sd, array[,] real level_length_scale, matrix run_own_cov) {
  return add_jitter(fidelity_cov(xt_sim, w_sim, kernel_id, level_sd, level_length_scale) + run_own_cov,
                    fidelity_variance(w_top, level_sd));
}

/**
 * Prior for the scales between fidelities when they are sampled with theta
 * (koh_emulator.stan; Kennedy & O'Hagan 2000, section 3): normal(1, 0.5).
 * Every level's runs are standardised on one scale, so a cheap simulator
 * that follows the expensive one has rho_k near 1; sd 0.5 lets the runs
 * move it anywhere in about (0, 2) and keeps a negative scale possible, not
 * likely. Not centred on stage 1's estimate, which the same runs made. Here
 * beside the weights it scales, not in priors.stan, so that only the
 * programs of several fidelities include it.
 *
 * @param rho each level's scale on the level below
 * @return log density
 */
real fidelity_scale_lpdf(vector rho) {
  return normal_lupdf(rho | 1, 0.5);
}
