/**
 * Functional calibration parameters theta_j(x) (review section 8.2;
 * Plumlee et al. 2016, Brown & Atamturktur 2018). On the unit scale of its
 * box, theta_j(x) = logistic(logit(level_j) + GP_j(x)), GP_j zero-mean: the
 * level has the same uniform prior as a scalar theta, and the GP moves
 * theta_j over the functional inputs without leaving its box.
 * functional_slot[j] = k > 0 when theta_j is the k-th functional one.
 */

/**
 * theta on the unit scale at each point.
 *
 * @param theta_unit levels of all Q parameters on [0, 1]
 * @param functional_slot 0 for a scalar theta, k for the k-th functional one
 * @param deviation GP_k values at the points (n x F); with F = 0, one row is returned
 * @return theta on the unit scale, one row per point (n x Q), or 1 x Q when none is functional
 */
matrix theta_unit_rows(vector theta_unit, array[] int functional_slot, matrix deviation) {
  int q = rows(theta_unit);
  int n = cols(deviation) == 0 ? 1 : rows(deviation);
  matrix[n, q] out;
  for (j in 1:q) {
    if (functional_slot[j] == 0) {
      out[:, j] = rep_vector(theta_unit[j], n);
    } else {
      out[:, j] = inv_logit(logit(theta_unit[j]) + deviation[:, functional_slot[j]]);
    }
  }
  return out;
}

/**
 * Rows of unit-scale theta in original units.
 */
matrix theta_rows_original(matrix unit_rows, vector lower_bound, vector upper_bound) {
  matrix[rows(unit_rows), cols(unit_rows)] out;
  for (i in 1:rows(unit_rows)) {
    out[i] = theta_from_unit(unit_rows[i]', lower_bound, upper_bound)';
  }
  return out;
}

/**
 * The GP deviations of the functional theta at the points (non-centred).
 *
 * @param x_fun functional inputs of the points, on the unit cube
 * @param marginal_sd, length_scale one GP per functional theta
 * @param z standard normals (n x F)
 * @return deviations (n x F)
 */
matrix functional_deviation(array[] vector x_fun, int kernel_id, vector marginal_sd,
                            array[] vector length_scale, matrix z) {
  matrix[rows(z), cols(z)] out;
  for (k in 1:cols(z)) {
    out[:, k] = latent_gp(x_fun, kernel_id, marginal_sd[k], to_array_1d(length_scale[k]), z[:, k]);
  }
  return out;
}
