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
 * One draw of each biased source's bias curve at new points: given the
 * residuals of every row the model conditions on (its first m rows the
 * simulator runs, which the biases do not touch), or from the prior under
 * prior_only (Rasmussen & Williams 2006, eqs. 2.23-2.24). Each curve is drawn
 * from its own marginal conditional, not jointly with delta or the other
 * sources' biases.
 *
 * @param resid the rows minus their prior means: m runs, then the physical rows
 * @param L Cholesky factor of resid's covariance, biases included
 * @param m the number of leading rows that are runs (0: physical rows only)
 * @param x the physical rows' simulator inputs, scaled to [0, 1]
 * @param x_new the new points' simulator inputs, scaled to [0, 1]
 * @param bias_of each physical row's biased source, 0 = a reference source
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param bias_sd each biased source's bias GP marginal sd
 * @param bias_length_scale its length scales, one row per biased source
 * @param normals given standard normals, size(x_new) x size(bias_sd), or 0 rows: Stan's RNG
 * @param prior_only 1 = draws from the prior
 * @return one row per biased source, one column per new point (standardised units)
 */
matrix source_bias_new_rng(vector resid, matrix L, int m, array[] vector x, array[] vector x_new,
                           array[] int bias_of, int kernel_id, array[] real bias_sd,
                           array[,] real bias_length_scale, matrix normals, int prior_only) {
  int n = size(x);
  int p = size(x_new);
  int n_bias = size(bias_sd);
  matrix[n_bias, p] out = rep_matrix(0, n_bias, p);
  for (b in 1:n_bias) {
    vector[p] z = rows(normals) == 0 ? std_normals_rng(p) : normals[:, b];
    matrix[p, p] K_new = ard_cov(x_new, kernel_id, bias_sd[b], bias_length_scale[b]);
    if (prior_only) {
      out[b] = gp_prior_draw(K_new, z)';
    } else {
      matrix[p, m + n] K_cross = rep_matrix(0, p, m + n);
      matrix[p, n] K_b = ard_cross_cov(x_new, x, kernel_id, bias_sd[b], bias_length_scale[b]);
      for (i in 1:n) {
        if (bias_of[i] == b) K_cross[:, m + i] = K_b[:, i];
      }
      out[b] = gp_conditional_draw(resid, L, K_cross, K_new, z)';
    }
  }
  return out;
}

/**
 * One draw of the biases at the physical rows themselves (0 at a reference
 * source's rows), for the replicated data y_rep: given the residuals, or from
 * the prior under prior_only. No random numbers are used without biased sources.
 *
 * @param resid the physical rows minus their prior means
 * @param L Cholesky factor of resid's covariance, biases included
 * @param K_bias source_bias_cov at the rows
 * @param n_bias the number of biased sources
 * @param prior_only 1 = draws from the prior
 * @return each row's bias, standardised units
 */
vector source_bias_at_rows_rng(vector resid, matrix L, matrix K_bias, int n_bias, int prior_only) {
  int n = rows(resid);
  if (n_bias == 0) return rep_vector(0, n);
  // a reference row's variance is 0: its draw is 0 up to the jitter, which add_jitter
  // scales to the biases' mean variance
  if (prior_only) return gp_prior_draw(K_bias, std_normals_rng(n));
  return gp_conditional_draw(resid, L, K_bias, K_bias, std_normals_rng(n));
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
