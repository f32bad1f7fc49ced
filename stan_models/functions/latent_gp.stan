/**
 * Latent GPs, for the programs whose likelihood does not let the GP be
 * integrated out (koh_latent*.stan). Non-centred: values = L z, z ~ N(0, I),
 * L the Cholesky factor of the covariance; centred: the values themselves,
 * values ~ N(0, L L'). Centred suits data that pin the values (much more
 * information per point than the prior's precision), non-centred data that
 * do not: each is a funnel, or a long ridge, where the other is not
 * (Papaspiliopoulos, Roberts & Skold 2007; Betancourt & Girolami 2015).
 */

/**
 * Cholesky factor of a latent GP's covariance at the points, with the
 * jitter (add_jitter) that keeps it positive definite where points repeat.
 *
 * @param x the points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd the GP's marginal sd
 * @param length_scale the GP's length scales, one per input
 * @return lower Cholesky factor, size(x) x size(x)
 */
matrix latent_gp_cholesky(array[] vector x, int kernel_id, real marginal_sd,
                          array[] real length_scale) {
  return cholesky_decompose(add_jitter(ard_cov(x, kernel_id, marginal_sd, length_scale),
                                       square(marginal_sd)));
}

/**
 * GP values at the points from standard normals z.
 *
 * @param x the points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd the GP's marginal sd
 * @param length_scale the GP's length scales, one per input
 * @param z standard normals, one per value drawn
 * @return the GP's values at the points, L z
 */
vector latent_gp(array[] vector x, int kernel_id, real marginal_sd,
                 array[] real length_scale, vector z) {
  return latent_gp_cholesky(x, kernel_id, marginal_sd, length_scale) * z;
}

/**
 * A latent GP's values at the points from the sampler's parameters: the
 * parameters themselves when centred, L z when non-centred.
 *
 * @param raw the sampled parameters: the values (centred) or their standard normals z
 * @param centred 1 = raw are the values, 0 = their standard normals
 * @param x the points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd the GP's marginal sd
 * @param length_scale the GP's length scales, one per input
 * @return the GP's values at the points
 */
vector latent_gp_values(vector raw, int centred, array[] vector x, int kernel_id, real marginal_sd,
                        array[] real length_scale) {
  if (centred) return raw;
  return latent_gp(x, kernel_id, marginal_sd, length_scale, raw);
}

/**
 * Prior of a latent GP's sampled parameters: the zero-mean GP on the values
 * when centred, standard normals when non-centred (the values are then a
 * transform of them, latent_gp_values). One Cholesky factor per call in the
 * centred case, none here in the non-centred one.
 *
 * @param raw the sampled parameters: the values (centred) or their standard normals z
 * @param centred 1 = raw are the values, 0 = their standard normals
 * @param x the points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd the GP's marginal sd
 * @param length_scale the GP's length scales, one per input
 * @return log density (constants dropped as by ~ when called as _lupdf)
 */
real latent_gp_prior_lpdf(vector raw, int centred, array[] vector x, int kernel_id, real marginal_sd,
                          array[] real length_scale) {
  if (centred) {
    return multi_normal_cholesky_lupdf(raw | rep_vector(0, rows(raw)),
                                       latent_gp_cholesky(x, kernel_id, marginal_sd, length_scale));
  }
  return std_normal_lupdf(raw);
}

/**
 * One draw of a latent GP at new points given its values at the points,
 * from standard normals z (one per new point).
 *
 * @param values the GP's values at the points
 * @param x the points
 * @param x_new the new points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd the GP's marginal sd
 * @param length_scale the GP's length scales, one per input
 * @param z standard normals, one per value drawn
 * @return the GP's values at the new points
 */
vector latent_gp_predict(vector values, array[] vector x, array[] vector x_new, int kernel_id,
                         real marginal_sd, array[] real length_scale, vector z) {
  return gp_conditional_draw(values, latent_gp_cholesky(x, kernel_id, marginal_sd, length_scale),
                             ard_cross_cov(x_new, x, kernel_id, marginal_sd, length_scale),
                             ard_cov(x_new, kernel_id, marginal_sd, length_scale), z);
}

/**
 * The emulated simulator at the physical points given the runs, as a latent
 * draw: f = mean + K_os K_ss^-1 (y_sim - mean) + chol(K_oo - K_os K_ss^-1 K_so) z.
 * The runs carry the nugget; f at the physical points does not.
 *
 * @param L_sim Cholesky factor of the runs' covariance, nugget included
 * @param xt_sim emulator inputs (x, theta on the unit cube) and standardised outputs of the runs
 * @param y_sim emulator inputs (x, theta on the unit cube) and standardised outputs of the runs
 * @param xt_obs emulator inputs of the physical points at their theta
 * @param z standard normals, one per physical point
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param emulator_mean the emulator GP's constant mean
 * @param emulator_sd the emulator GP's marginal sd
 * @param emulator_length_scale the emulator GP's length scales: inputs first, then theta
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
  // symmetrised against round-off
  return mean_obs + cholesky_decompose(add_jitter(0.5 * (cov_obs + cov_obs'), square(emulator_sd))) * z;
}

/**
 * The generated quantities at the prediction points that both latent programs
 * share: the discrepancy given its latent values at the physical points, the
 * real process, and a new observation.
 *
 * @param likelihood_id the observation model (observation_model.stan)
 * @param f_link_new the simulator at the prediction points, model scale
 * @param mean_terms_new the discrepancy's mean terms h_new * beta at the prediction points, model scale
 * @param delta the latent discrepancy GP at the physical points, model scale
 * @param x_delta discrepancy inputs of the physical and the prediction points
 * @param x_delta_new discrepancy inputs of the physical and the prediction points
 * @param delta_sd the discrepancy's hyperparameters (empty: none)
 * @param delta_length_scale the discrepancy's hyperparameters (empty: none)
 * @param normals_new standard normals for the draws at the prediction points
 *        (prediction_normals_rng): column 2 for delta
 * @param sd_obs the Gaussian noise sd and negative binomial precision
 * @param precision the Gaussian noise sd and negative binomial precision
 * @param trials_new binomial trials of a new observation at each prediction point
 * @param units discrepancy units (discrepancy_units)
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return (f_new, delta_new, zeta_new, y_new), original units
 */
tuple(vector, vector, vector, vector) latent_prediction_quantities_rng(
    int likelihood_id, vector f_link_new, vector mean_terms_new, vector delta, array[] vector x_delta,
    array[] vector x_delta_new, int kernel_id, array[] real delta_sd,
    array[] real delta_length_scale, matrix normals_new, real sd_obs, real precision,
    array[] int trials_new, real units, real y_center, real y_scale) {
  int p = rows(f_link_new);
  vector[p] delta_new = mean_terms_new;
  if (size(delta_sd) > 0) {
    delta_new += latent_gp_predict(delta, x_delta, x_delta_new, kernel_id, delta_sd[1], delta_length_scale,
                                  prediction_normals_rng(normals_new, 2, p));
  }
  vector[p] eta_new = f_link_new + delta_new;
  return (response_scale(likelihood_id, f_link_new, y_center, y_scale),
          units * delta_new,
          response_scale(likelihood_id, eta_new, y_center, y_scale),
          observations_original_units(
            likelihood_id, observation_rng(likelihood_id, eta_new, sd_obs, precision, trials_new),
            y_center, y_scale));
}
