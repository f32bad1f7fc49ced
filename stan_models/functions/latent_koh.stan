/**
 * What the two latent programs (koh_latent.stan, koh_latent_emulator.stan)
 * share around their different simulator parts: the observation model's
 * parameters, the functional theta's prior, and the generated quantities at
 * the physical points and on the functional theta's grid.
 */

/**
 * The Gaussian observation sd, or 1 where the likelihood has none.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param noise_sd the noise sd (one value for gaussian, else empty)
 * @return noise_sd[1] for gaussian, else 1
 */
real observation_sd(int likelihood_id, array[] real noise_sd) {
  return likelihood_id == 1 ? noise_sd[1] : 1;
}

/**
 * The negative binomial precision phi = 1 / inv_sqrt_phi^2, or 1 where the
 * likelihood has none.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param inv_sqrt_phi the overdispersion (one value for negbinomial, else empty)
 * @return phi for negbinomial, else 1
 */
real negbinomial_precision(int likelihood_id, array[] real inv_sqrt_phi) {
  return likelihood_id == 3 ? inv_square(inv_sqrt_phi[1]) : 1;
}

/**
 * Prior of the functional theta's values at the distinct points: their GP
 * (functional_theta_lpdf) on the logit values when centred, standard normals
 * on the raw values otherwise (the logit values are then a transform of them).
 *
 * @param logit_values N_fun x F logit of each functional theta (unit scale)
 * @param raw N_fun x F the sampled values: the logit values or standard normals
 * @param centred 1 = raw are the logit values, 0 = their standard normals
 * @param theta_unit every theta on [0, 1]; a functional theta's level
 * @param functional_slot 0 = scalar theta, k = the k-th functional one
 * @param x_fun the distinct values of the functional inputs
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd one GP sd per functional theta, logit scale
 * @param length_scale one GP's length scales per functional theta
 * @return log density (constants dropped as by ~ when called as _lupdf)
 */
real functional_theta_prior_lpdf(matrix logit_values, matrix raw, int centred, vector theta_unit,
                                 array[] int functional_slot, array[] vector x_fun, int kernel_id,
                                 vector marginal_sd, array[] vector length_scale) {
  if (centred) {
    return functional_theta_lupdf(logit_values | theta_unit, functional_slot, x_fun, kernel_id, marginal_sd,
                                  length_scale);
  }
  return std_normal_lupdf(to_vector(raw));
}

/**
 * The generated quantities at the physical points, original units
 * (latent_observation_quantities_rng), with the Cholesky factor of the
 * discrepancy's prior built here.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param eta_rest the linear predictor without the discrepancy GP, model scale
 * @param delta the latent discrepancy GP at the points, model scale
 * @param x_delta the discrepancy inputs of the points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param delta_sd the discrepancy's marginal sd (empty without a discrepancy)
 * @param delta_length_scale its length scales
 * @param sd_obs Gaussian observation sd (observation_sd)
 * @param precision negative binomial precision (negbinomial_precision)
 * @param y_real Gaussian outputs, standardised
 * @param y_int counts or successes
 * @param trials binomial trials
 * @param censoring 0 = observed, 1 = left, 2 = right, 3 = interval
 * @param lower_bound censoring bounds, standardised like y_real
 * @param upper_bound see lower_bound
 * @param y_center original-scale y = y_center + y_scale * y
 * @param y_scale see y_center
 * @param rule normal quadrature nodes and weights (normal_quadrature)
 * @return (log p(y_i | delta_-i, parameters), E(y_i | delta_-i, parameters), replicated data)
 */
tuple(vector, vector, vector) latent_point_quantities_rng(
    int likelihood_id, vector eta_rest, vector delta, array[] vector x_delta, int kernel_id,
    array[] real delta_sd, array[] real delta_length_scale, real sd_obs, real precision, vector y_real,
    array[] int y_int, array[] int trials, array[] int censoring, vector lower_bound, vector upper_bound,
    real y_center, real y_scale, tuple(vector, vector) rule) {
  int n_delta = size(delta_sd) > 0 ? rows(delta) : 0;
  matrix[n_delta, n_delta] L_delta = rep_matrix(0, n_delta, n_delta);  // Cholesky factor of delta's prior
  if (size(delta_sd) > 0) {
    L_delta = latent_gp_cholesky(x_delta, kernel_id, delta_sd[1], delta_length_scale);
  }
  return latent_observation_quantities_rng(
    likelihood_id, eta_rest, delta, L_delta, sd_obs, precision, y_real, y_int, trials, censoring,
    lower_bound, upper_bound, y_center, y_scale, rule);
}

/**
 * The functional theta on the grid (original units) and every theta at the
 * prediction points (unit scale), given their values at the distinct points,
 * drawn in this order.
 *
 * @param theta_unit every theta on [0, 1]; a functional theta's level
 * @param functional_slot 0 = scalar theta, k = the k-th functional one
 * @param logit_values N_fun x F logit of each functional theta at x_fun
 * @param x_fun the distinct values of the functional inputs
 * @param x_fun_grid the grid
 * @param x_fun_new the functional inputs of the prediction points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd one GP sd per functional theta, logit scale
 * @param length_scale one GP's length scales per functional theta
 * @param theta_lower lower bounds of theta, original units
 * @param theta_upper upper bounds of theta, original units
 * @param normals_new given standard normals for the prediction points (prediction_normals_rng)
 * @return (G x F functional theta on the grid, P x Q theta at the prediction points on [0, 1])
 */
tuple(matrix, matrix) functional_theta_quantities_rng(
    vector theta_unit, array[] int functional_slot, matrix logit_values, array[] vector x_fun,
    array[] vector x_fun_grid, array[] vector x_fun_new, int kernel_id, vector marginal_sd,
    array[] vector length_scale, vector theta_lower, vector theta_upper, matrix normals_new) {
  int F = cols(logit_values);
  int P = size(x_fun_new);
  matrix[size(x_fun_grid), F] grid = theta_function_grid_rng(
    theta_unit, functional_slot, logit_values, x_fun, x_fun_grid, kernel_id, marginal_sd, length_scale,
    theta_lower, theta_upper);
  matrix[P, rows(theta_unit)] theta_new_unit = theta_unit_rows_draw(
    theta_unit, functional_slot, logit_values, x_fun, x_fun_new, kernel_id, marginal_sd, length_scale,
    functional_normals_rng(normals_new, F, P));
  return (grid, theta_new_unit);
}
