/**
 * The emulator of a vector output at the experiments' settings, one GP per
 * basis component (Higdon et al. 2008, section 2.2), hyperparameters fixed
 * after stage 1 (stancal.vector_emulator): given the runs' weights, the
 * weights at the experiments' (x_e, theta) are normal, independent between
 * components. Squared-exponential kernel, as stage 1's.
 *
 * @param points (x_e, theta, theta_e) of each experiment, unit cube
 * @param xt_runs (x, theta) of each run, unit cube
 * @param L_runs Cholesky factor of the runs' covariance
 * @param alpha K^-1 (run weights - mean)
 * @param mean, sd, length_scale the component's hyperparameters
 * @return (weight means at the experiments, their covariance)
 */
tuple(vector, matrix) component_weights(array[] vector points, array[] vector xt_runs, matrix L_runs,
                                        vector alpha, real mean, real sd, array[] real length_scale) {
  matrix[size(points), size(xt_runs)] cross = gp_exp_quad_cov(points, xt_runs, sd, length_scale);
  matrix[size(xt_runs), size(points)] A = mdivide_left_tri_low(L_runs, cross');
  return (mean + cross * alpha, gp_exp_quad_cov(points, sd, length_scale) - crossprod(A));
}

/**
 * component_weights for every component, at each experiment's emulator
 * inputs (x_e, theta, theta_e).
 *
 * @param x each experiment's inputs; theta_unit, theta_exp_unit shared and
 *        per-experiment parameters, all on the unit cube
 * @param xt_runs, L_runs, alpha the runs, per component where it matters
 * @param emulator_mean, emulator_sd, emulator_length_scale stage 1, per component
 * @return (weight means, experiments x components; per component, the
 *         weights' covariance between experiments)
 */
tuple(matrix, array[] matrix) experiment_weights(array[] vector x, vector theta_unit, array[] vector theta_exp_unit,
                                                array[] vector xt_runs, array[] matrix L_runs, matrix alpha,
                                                vector emulator_mean, vector emulator_sd,
                                                array[,] real emulator_length_scale) {
  int n_exp = size(x);
  int n_comp = cols(alpha);
  array[n_exp] vector[rows(x[1]) + rows(theta_unit) + rows(theta_exp_unit[1])] points;
  for (e in 1:n_exp) points[e] = append_row(x[e], append_row(theta_unit, theta_exp_unit[e]));
  matrix[n_exp, n_comp] means;
  array[n_comp] matrix[n_exp, n_exp] covariances;
  for (c in 1:n_comp) {
    tuple(vector[n_exp], matrix[n_exp, n_exp]) w
      = component_weights(points, xt_runs, L_runs[c], alpha[:, c], emulator_mean[c], emulator_sd[c],
                          emulator_length_scale[c]);
    means[:, c] = w.1;
    covariances[c] = w.2;
  }
  return (means, covariances);
}

/**
 * Covariance between two sets of measured values (rows a and b) of what
 * the basis mean does not give: the emulator's weight uncertainty through
 * the components, plus the discrepancy GP over (inputs, output index).
 *
 * @param experiment_a, components_a, x_delta_a rows a: their experiment,
 *        the basis components at their index, (inputs, index) on the unit cube
 * @param experiment_b, components_b, x_delta_b the same for rows b
 * @param weight_cov per component, the weights' covariance between experiments
 * @param delta_sd, delta_length_scale the discrepancy (size 0: none)
 * @return covariance, rows a x rows b
 */
matrix signal_cov(array[] int experiment_a, matrix components_a, array[] vector x_delta_a,
                  array[] int experiment_b, matrix components_b, array[] vector x_delta_b,
                  array[] matrix weight_cov, array[] real delta_sd, array[] real delta_length_scale) {
  matrix[size(experiment_a), size(experiment_b)] K = rep_matrix(0, size(experiment_a), size(experiment_b));
  for (c in 1:size(weight_cov)) {
    K += diag_pre_multiply(components_a[:, c],
                           diag_post_multiply(weight_cov[c][experiment_a, experiment_b], components_b[:, c]));
  }
  if (size(delta_sd) > 0) {
    K += gp_exp_quad_cov(x_delta_a, x_delta_b, delta_sd[1], delta_length_scale);
  }
  return K;
}

/**
 * Each measured value's independent variance: its known noise, one noise
 * sd for all, or one per experiment (noise_mode 0, 1, 2).
 */
vector independent_variance(int noise_mode, vector known_noise_sd, array[] real noise_sd,
                            array[] int experiment) {
  if (noise_mode == 0) return square(known_noise_sd);
  if (noise_mode == 1) return rep_vector(square(noise_sd[1]), size(experiment));
  return square(to_vector(noise_sd)[experiment]);
}
