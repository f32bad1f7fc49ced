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
