/**
 * Biased measurement sources (docs/noise.md; review section 8.1.3): the
 * measurement bias of Gu, Anderson & McPhillips (2023, "Calibration of
 * imperfect geophysical models by multiple satellite interferograms with
 * measurement bias", Technometrics 65), a GP over the inputs beside the model
 * discrepancy, as the R package RobustCalibration fits it for several sources
 * of data. A reading of row i by source s is
 *   y_i = zeta(x_i) + b_s(x_i) + eps_i,   b_s ~ GP(0, k_s) for each biased source s,
 * and b_s = 0 for a reference source. The biases are independent of each other
 * and of the shared discrepancy delta, so with the GPs integrated out the rows'
 * covariance gains the block term
 *   k_s(x_i, x_j) * [source(i) = source(j) = s]
 * beside delta's kernel. The references see delta alone: they anchor the level,
 * and b_s is what source s's rows disagree with them by at the same or nearby
 * inputs. Each k_s has its own marginal sd and length scales over the simulator
 * inputs (on [0, 1]), with delta's priors (priors.stan).
 */

/**
 * The biases' covariance among the physical rows: k_s(x_i, x_j) where rows i
 * and j are both read by biased source s, else 0.
 *
 * @param x the rows' simulator inputs, scaled to [0, 1]
 * @param bias_of each row's biased source, 1..size(bias_sd), 0 = a reference source
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2 (delta's kernel)
 * @param bias_sd each biased source's bias GP marginal sd (empty: no biased source)
 * @param bias_length_scale its length scales, one row per biased source
 * @return covariance matrix, size(x) x size(x)
 */
matrix source_bias_cov(array[] vector x, array[] int bias_of, int kernel_id, array[] real bias_sd,
                       array[,] real bias_length_scale) {
  int n = size(x);
  matrix[n, n] K = rep_matrix(0, n, n);
  for (b in 1:size(bias_sd)) {
    array[n] int rows_b = rep_array(1, n);  // its first count entries: source b's rows
    int count = 0;
    for (i in 1:n) {
      if (bias_of[i] == b) {
        count += 1;
        rows_b[count] = i;
      }
    }
    if (count > 0) {
      K[rows_b[1:count], rows_b[1:count]] = ard_cov(x[rows_b[1:count]], kernel_id, bias_sd[b],
                                                    bias_length_scale[b]);
    }
  }
  return K;
}

/**
 * The biases' covariances for one joint draw with the other GP terms the rows
 * see (delta; on the emulator programs, f too): given the data, a biased
 * source's bias and the process zeta are correlated (its readings tell their
 * sum, and the references zeta alone), so a biased reading's zeta + b_s is
 * drawn right only from one conditional of every term (source_bias_joint_draw,
 * koh_joint.stan's koh_joint_quantities_rng), not each from its own. The
 * biases at the new points are stacked source by source: biased source 1's
 * values at every new point, then source 2's, and so on. At the rows, a
 * reference source's row has bias variance 0: its draw is 0 up to the
 * conditional draw's jitter (gp_conditional_draw).
 *
 * @param x the physical rows' simulator inputs, scaled to [0, 1]
 * @param x_new the new points' simulator inputs, scaled to [0, 1]
 * @param bias_of each physical row's biased source, 1..size(bias_sd), 0 = a reference source
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param bias_sd each biased source's bias GP marginal sd (empty: no biased source)
 * @param bias_length_scale its length scales, one row per biased source
 * @return (the rows' biases' covariance, source_bias_cov, size(x) square, or 0 x 0 without a biased
 *         source: then there are no biases at the rows to draw;
 *         the new points' biases' covariance with the rows, size(bias_sd) * size(x_new) x size(x);
 *         their prior covariance, block diagonal: the biases are independent a priori)
 */
tuple(matrix, matrix, matrix) source_bias_blocks(array[] vector x, array[] vector x_new, array[] int bias_of,
                                                 int kernel_id, array[] real bias_sd,
                                                 array[,] real bias_length_scale) {
  int n = size(x);
  int p = size(x_new);
  int n_bias = size(bias_sd);
  int n_rows = n_bias > 0 ? n : 0;
  matrix[n_rows, n_rows] at_rows = n_bias > 0 ? source_bias_cov(x, bias_of, kernel_id, bias_sd, bias_length_scale)
                                              : rep_matrix(0, 0, 0);
  matrix[n_bias * p, n] cross = rep_matrix(0, n_bias * p, n);
  matrix[n_bias * p, n_bias * p] at_new = rep_matrix(0, n_bias * p, n_bias * p);
  for (b in 1:(p > 0 ? n_bias : 0)) {
    int first = (b - 1) * p + 1;
    matrix[p, n] K_b = ard_cross_cov(x_new, x, kernel_id, bias_sd[b], bias_length_scale[b]);
    for (i in 1:n) {
      if (bias_of[i] == b) cross[first:(b * p), i] = K_b[:, i];  // source b's rows only
    }
    at_new[first:(b * p), first:(b * p)] = ard_cov(x_new, kernel_id, bias_sd[b], bias_length_scale[b]);
  }
  return (at_rows, cross, at_new);
}

/**
 * Standard normals for the bias curves at the new points, stacked as
 * source_bias_blocks stacks the values (source by source): the given ones,
 * or Stan's RNG when none are given (rows = 0), as prediction_normals_rng.
 *
 * @param given P x n_bias standard normals (bias_normals_new), or 0 x n_bias
 * @param n_bias the number of biased sources
 * @param p the number of new points
 * @return n_bias * p standard normals
 */
vector source_bias_normals_rng(matrix given, int n_bias, int p) {
  if (rows(given) == 0) return std_normals_rng(n_bias * p);
  return to_vector(given);  // column by column: source 1's p values, then source 2's
}

/**
 * One joint draw of another GP term that the rows see (koh.stan's delta) and
 * the biases, independent a priori, given the residuals both enter (the
 * stacked values [a; b]; Rasmussen & Williams 2006, eqs. 2.23-2.24), or from
 * their prior under prior_only. Given the data the two are correlated, so
 * only a joint draw gives a biased reading's zeta + b_s its spread; each part
 * alone keeps its own conditional.
 *
 * @param resid observed values minus their prior mean
 * @param L_obs Cholesky factor of the covariance of resid, the biases included
 * @param K_cross_a the other term's values' covariance with resid (0 rows: none)
 * @param K_new_a their prior covariance
 * @param K_cross_b the biases' values' covariance with resid (0 rows: none)
 * @param K_new_b their prior covariance
 * @param z standard normals, rows(K_new_a) + rows(K_new_b)
 * @param prior_only 1 = draws from the prior
 * @return one draw of [a; b] minus their prior means
 */
vector source_bias_joint_draw(vector resid, matrix L_obs, matrix K_cross_a, matrix K_new_a, matrix K_cross_b,
                              matrix K_new_b, vector z, int prior_only) {
  int k_a = rows(K_new_a);
  int k = k_a + rows(K_new_b);
  if (k == 0) return rep_vector(0, 0);
  matrix[k, k] K_new = rep_matrix(0, k, k);  // block diagonal: the terms are independent a priori
  K_new[1:k_a, 1:k_a] = K_new_a;
  K_new[(k_a + 1):k, (k_a + 1):k] = K_new_b;
  if (prior_only) return gp_prior_draw(K_new, z);
  return gp_conditional_draw(resid, L_obs, append_row(K_cross_a, K_cross_b), K_new, z);
}

/**
 * The prior variance of the GPs integrated out beside the noise, the scale of
 * their covariance's jitter (add_jitter): the discrepancy's and the biases'
 * marginal variances summed (delta's alone without biased sources).
 *
 * @param delta_sd the discrepancy's marginal sd (empty: no discrepancy)
 * @param bias_sd each biased source's bias GP marginal sd (empty: none)
 * @return the summed variance
 */
real gp_variance(array[] real delta_sd, array[] real bias_sd) {
  return sum(square(to_vector(delta_sd))) + sum(square(to_vector(bias_sd)));
}
