/**
 * The emulator of a vector output's basis weights when the runs come from
 * simulators of several fidelities, cheapest first (Kennedy & O'Hagan 2000,
 * section 2.2; Le Gratiet & Garnier 2014 for stage 1, level by level):
 * each component's weight has its own autoregressive emulator,
 *   w_1 = g_1,   w_k = rho_k w_(k-1) + g_k,
 * with independent GPs g_k over (x, theta) and a constant rho_k per
 * component (fidelity.stan's weights and covariances). The basis is the
 * calibrated (top-level) simulator's runs' (Higdon et al. 2008); the
 * cheaper runs enter as their projections on it. The experiments see the
 * top level. Hyperparameters fixed after stage 1 (stancal.numerics.vector_emulator).
 */

/**
 * One component's weights at the experiments' settings (component_weights
 * of vector_output.stan, with several fidelities): normal, its mean given
 * every run of every level, its covariance given the variance runs (a
 * subset: never more certain than given all), plus the top level's own
 * nugget where two points are one.
 *
 * @param points (x_e, theta, theta_e) of each experiment, unit cube
 * @param xt_runs (x, theta) of every run of every level, unit cube
 * @param w_runs each run's weights on the levels' GPs (rows of fidelity_weights)
 * @param alpha K^-1 (run weights - their level's mean), over every run
 * @param variance_runs the runs the covariance conditions on
 * @param L_variance the Cholesky factor of their covariance (fidelity_run_cov)
 * @param w_top the top level's weights on the levels' GPs
 * @param top_mean the top level's prior mean, sum_j w_top_j mean_j
 * @param level_sd each level's GP marginal sd, cheapest first
 * @param level_length_scale each level's GP length scales
 * @param nugget the top level's own nugget sd
 * @param same_point 1 where two points are identical, else 0
 * @return (weight means at the points, their covariance)
 */
tuple(vector, matrix) fidelity_component_weights(array[] vector points, array[] vector xt_runs, matrix w_runs,
                                                 vector alpha, array[] int variance_runs, matrix L_variance,
                                                 row_vector w_top, real top_mean, array[] real level_sd,
                                                 array[,] real level_length_scale, real nugget, matrix same_point) {
  matrix[size(points), cols(w_top)] w_points = rep_matrix(w_top, size(points));
  matrix[size(variance_runs), size(points)] A = mdivide_left_tri_low(L_variance, fidelity_cross_cov(
    xt_runs[variance_runs], w_runs[variance_runs], points, w_points, 1, level_sd, level_length_scale));
  return (top_mean + fidelity_cross_cov(points, w_points, xt_runs, w_runs, 1, level_sd, level_length_scale) * alpha,
          fidelity_cov(points, w_points, 1, level_sd, level_length_scale) + square(nugget) * same_point
          - crossprod(A));
}

/**
 * fidelity_component_weights for every component, at each experiment's
 * emulator inputs (experiment_weights of vector_output.stan, with several fidelities).
 *
 * @param points (x_e, theta, theta_e) of each experiment, unit cube (emulator_points)
 * @param xt_runs every run of every level
 * @param w_runs per component, each run's weights on the levels' GPs
 * @param alpha per component (columns), K^-1 (run weights - their level's mean)
 * @param variance_runs the runs the covariances condition on
 * @param L_variance per component, the Cholesky factor of their covariance
 * @param w_top per component, the top level's weights
 * @param top_mean per component, the top level's prior mean
 * @param level_sd per component, each level's GP sd
 * @param level_length_scale per component, each level's GP length scales
 * @param nugget per component, the top level's own nugget sd
 * @param same_point 1 where two experiments' emulator inputs are identical, else 0
 * @return (weight means, experiments x components; per component, the
 *         weights' covariance between experiments)
 */
tuple(matrix, array[] matrix) fidelity_experiment_weights(array[] vector points, array[] vector xt_runs,
                                                         array[] matrix w_runs, matrix alpha,
                                                         array[] int variance_runs, array[] matrix L_variance,
                                                         array[] row_vector w_top, vector top_mean,
                                                         array[,] real level_sd, array[,,] real level_length_scale,
                                                         vector nugget, matrix same_point) {
  int n_exp = size(points);
  int n_comp = cols(alpha);
  matrix[n_exp, n_comp] means;
  array[n_comp] matrix[n_exp, n_exp] covariances;
  for (c in 1:n_comp) {
    tuple(vector[n_exp], matrix[n_exp, n_exp]) w
      = fidelity_component_weights(points, xt_runs, w_runs[c], alpha[:, c], variance_runs, L_variance[c], w_top[c],
                                   top_mean[c], level_sd[c], level_length_scale[c], nugget[c], same_point);
    means[:, c] = w.1;
    covariances[c] = w.2;
  }
  return (means, covariances);
}
