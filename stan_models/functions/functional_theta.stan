/**
 * Functional calibration parameters theta_j(x) (review section 8.2;
 * Plumlee et al. 2016, Brown & Atamturktur 2018). On the unit scale of its
 * box, theta_j(x) = logistic(g_j(x)) with g_j ~ GP(logit(level_j), K_j): the
 * level has the same uniform prior as a scalar theta, and theta_j(x) never
 * leaves its box. g_j lives at the distinct functional-input values, centred
 * (the parameters are g_j: best when the data pin theta(x) closely) or
 * non-centred (g_j = logit(level) + L z with z standard normal: best when they
 * do not, where the centred form is a funnel in the GP's sd).
 * functional_slot[j] = k > 0 when theta_j is the k-th functional one.
 */

/**
 * theta on the unit scale at each point.
 *
 * @param theta_unit levels of all Q parameters on [0, 1]
 * @param functional_slot 0 for a scalar theta, k for the k-th functional one
 * @param logit_values g_k at the points (n x F); with F = 0, one row is returned
 * @return theta on the unit scale, one row per point (n x Q), or 1 x Q when none is functional
 */
matrix theta_unit_rows(vector theta_unit, array[] int functional_slot, matrix logit_values) {
  int q = rows(theta_unit);
  int n = cols(logit_values) == 0 ? 1 : rows(logit_values);
  matrix[n, q] out;
  for (j in 1:q) {
    if (functional_slot[j] == 0) {
      out[:, j] = rep_vector(theta_unit[j], n);
    } else {
      out[:, j] = inv_logit(logit_values[:, functional_slot[j]]);
    }
  }
  return out;
}

/**
 * Rows of unit-scale theta in original units.
 *
 * @param unit_rows theta on [0, 1], one row per point (or one shared row)
 * @param lower_bound lower bounds of theta, original units
 * @param upper_bound upper bounds of theta, original units
 * @return theta in original units, the same rows
 */
matrix theta_rows_original(matrix unit_rows, vector lower_bound, vector upper_bound) {
  matrix[rows(unit_rows), cols(unit_rows)] out;
  for (i in 1:rows(unit_rows)) {
    out[i] = theta_from_unit(unit_rows[i]', lower_bound, upper_bound)';
  }
  return out;
}

/**
 * The functional thetas' logit values at the distinct points from the
 * sampler's parameters: themselves when centred, else logit(level) + L z.
 *
 * @param raw the parameters (n x F): the logit values, or their standard normals z
 * @param centred 1 = raw are the logit values, 0 = their standard normals
 * @param theta_unit every theta on [0, 1]; a functional theta's level
 * @param functional_slot 0 = scalar theta, k = the k-th functional one
 * @param x_fun the distinct values of the functional inputs, scaled to [0, 1]
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd one GP marginal sd per functional theta, logit scale
 * @param length_scale one GP's length scales per functional theta
 * @return the logit values g_k at the distinct points (n x F)
 */
matrix functional_logit_values(matrix raw, int centred, vector theta_unit, array[] int functional_slot,
                               array[] vector x_fun, int kernel_id, vector marginal_sd,
                               array[] vector length_scale) {
  if (centred) return raw;
  matrix[rows(raw), cols(raw)] out = raw;  // every column is overwritten: one per functional theta
  for (j in 1:rows(theta_unit)) {
    int k = functional_slot[j];
    if (k > 0) {
      out[:, k] = logit(theta_unit[j])
                  + latent_gp_cholesky(x_fun, kernel_id, marginal_sd[k], to_array_1d(length_scale[k])) * raw[:, k];
    }
  }
  return out;
}

/**
 * GP prior of the functional theta's logit values at the distinct points.
 *
 * @param logit_values g_k at the distinct functional-input values (n x F)
 * @param theta_unit levels of all parameters; the GP mean of g_k is logit(level)
 * @param x_fun the distinct functional-input values, on the unit cube
 * @param marginal_sd one GP per functional theta
 * @param length_scale one GP per functional theta
 * @param functional_slot 0 = scalar theta, k = the k-th functional one
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @return log density
 */
real functional_theta_lpdf(matrix logit_values, vector theta_unit, array[] int functional_slot,
                           array[] vector x_fun, int kernel_id, vector marginal_sd,
                           array[] vector length_scale) {
  real lp = 0;
  for (j in 1:rows(theta_unit)) {
    int k = functional_slot[j];
    if (k > 0) {
      lp += multi_normal_cholesky_lpdf(logit_values[:, k] | rep_vector(logit(theta_unit[j]), rows(logit_values)),
                                       latent_gp_cholesky(x_fun, kernel_id, marginal_sd[k],
                                                          to_array_1d(length_scale[k])));
    }
  }
  return lp;
}

/**
 * One posterior draw of theta_j(x) on the unit scale at new points, given
 * its logit values at the distinct points, from standard normals z (one per
 * new point).
 *
 * @param logit_values theta_j's logit (unit scale) at x_fun
 * @param level the functional theta's level on [0, 1] (its mean's inverse logit)
 * @param x_fun the distinct values of the functional inputs, scaled to [0, 1]
 * @param x_new the new points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd its GP's marginal sd, logit scale
 * @param length_scale its GP's length scales, one per functional input
 * @param z standard normals, one per value drawn
 * @return theta_j on [0, 1] at the new points
 */
vector functional_theta_predict(vector logit_values, real level, array[] vector x_fun,
                                array[] vector x_new, int kernel_id, real marginal_sd,
                                vector length_scale, vector z) {
  return inv_logit(logit(level) + latent_gp_predict(logit_values - logit(level), x_fun, x_new,
                                                    kernel_id, marginal_sd, to_array_1d(length_scale), z));
}

/**
 * One posterior draw of every theta on the unit scale at new points: the
 * functional ones from their GP given the distinct points, the scalar ones
 * repeated.
 *
 * @param z standard normals: column k for the k-th functional theta, one row per new point
 * @param theta_unit every theta on [0, 1]; a functional theta's level
 * @param functional_slot 0 = scalar theta, k = the k-th functional one
 * @param logit_values N_fun x F logit of each functional theta (unit scale) at x_fun
 * @param x_fun the distinct values of the functional inputs, scaled to [0, 1]
 * @param x_new the new points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd one GP marginal sd per functional theta, logit scale
 * @param length_scale one GP's length scales per functional theta
 * @return theta on the unit scale, one row per new point
 */
matrix theta_unit_rows_draw(vector theta_unit, array[] int functional_slot, matrix logit_values,
                            array[] vector x_fun, array[] vector x_new, int kernel_id,
                            vector marginal_sd, array[] vector length_scale, matrix z) {
  matrix[size(x_new), rows(theta_unit)] out = rep_matrix(theta_unit', size(x_new));
  for (j in 1:rows(theta_unit)) {
    int k = functional_slot[j];
    if (k > 0) {
      out[:, j] = functional_theta_predict(logit_values[:, k], theta_unit[j], x_fun, x_new,
                                           kernel_id, marginal_sd[k], length_scale[k], z[:, k]);
    }
  }
  return out;
}

/**
 * Standard normals for the functional theta at the prediction points:
 * columns 3 to 2 + F of the given ones (see prediction_normals_rng).
 *
 * @param given P x columns given standard normals, or 0 x columns
 * @param F the number of functional theta
 * @param n the number of values
 * @return P x F standard normals
 */
matrix functional_normals_rng(matrix given, int F, int n) {
  matrix[n, F] z;
  for (k in 1:F) z[:, k] = prediction_normals_rng(given, 2 + k, n);
  return z;
}

/**
 * The functional theta's columns of unit-scale rows, in original units.
 *
 * @param unit_rows theta on [0, 1], one row per point (or one shared row)
 * @param functional_slot 0 = scalar theta, k = the k-th functional one
 * @param lower_bound lower bounds of theta, original units
 * @param upper_bound upper bounds of theta, original units
 * @return one column per functional theta (rows(unit_rows) x F)
 */
matrix functional_columns_original(matrix unit_rows, array[] int functional_slot,
                                   vector lower_bound, vector upper_bound) {
  matrix[rows(unit_rows), max(append_array({0}, functional_slot))] out = rep_matrix(0, rows(unit_rows), max(append_array({0}, functional_slot)));
  for (j in 1:cols(unit_rows)) {
    int k = functional_slot[j];
    if (k > 0) out[:, k] = lower_bound[j] + (upper_bound[j] - lower_bound[j]) * unit_rows[:, j];
  }
  return out;
}

/**
 * One posterior draw of each functional theta on its grid, original units,
 * for the theta(x) curves of the report.
 *
 * @param theta_unit every theta on [0, 1]; a functional theta's level
 * @param functional_slot 0 = scalar theta, k = the k-th functional one
 * @param logit_values N_fun x F logit of each functional theta (unit scale) at x_fun
 * @param x_fun the distinct values of the functional inputs, scaled to [0, 1]
 * @param x_fun_grid the grid of functional inputs
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd one GP marginal sd per functional theta, logit scale
 * @param length_scale one GP's length scales per functional theta
 * @param theta_lower lower bounds of theta, original units
 * @param theta_upper upper bounds of theta, original units
 * @return one column per functional theta, one row per grid point
 */
matrix theta_function_grid_rng(vector theta_unit, array[] int functional_slot, matrix logit_values,
                               array[] vector x_fun, array[] vector x_fun_grid, int kernel_id,
                               vector marginal_sd, array[] vector length_scale,
                               vector theta_lower, vector theta_upper) {
  int g = size(x_fun_grid);
  int f = cols(logit_values);
  return functional_columns_original(
    theta_unit_rows_draw(theta_unit, functional_slot, logit_values, x_fun, x_fun_grid, kernel_id,
                         marginal_sd, length_scale, to_matrix(std_normals_rng(g * f), g, f)),
    functional_slot, theta_lower, theta_upper);
}
