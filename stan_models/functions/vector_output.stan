/**
 * The emulator of a vector output at the experiments' settings, one GP per
 * basis component (Higdon et al. 2008, section 2.2), hyperparameters fixed
 * after stage 1 (stancal.vector_emulator): given the runs' weights, the
 * weights at the experiments' (x_e, theta) are normal, independent between
 * components. Squared-exponential kernel, as stage 1's.
 *
 * The mean conditions on every run; the covariance on a subset (the
 * subset of data approximation, conservative: fewer runs never give a
 * smaller variance), so each gradient costs O(subset^2), not O(runs^2).
 *
 * The covariance keeps the weight GP's nugget where two points are one
 * (same_point): the nugget is the part of the runs' weights a smooth GP
 * does not follow (the simulator's numerical jitter), and the simulator at
 * the experiments has it as much as at the runs (Higdon et al. 2008,
 * section 2.2; SEPIA adds 1/lamWs to the experiments' weight covariance
 * too). The simulator is deterministic, so points at one input share one
 * jitter. Left out, the emulator is surest right at its runs, where its
 * error is the nugget's, and least sure in the theta box's corners: chains
 * then settle in the corners (docs/vector.md).
 *
 * @param points (x_e, theta, theta_e) of each experiment, unit cube
 * @param xt_runs (x, theta) of each run, unit cube
 * @param alpha K^-1 (run weights - mean), over every run
 * @param xt_variance the variance runs and the Cholesky factor of their covariance
 * @param L_variance the variance runs and the Cholesky factor of their covariance
 * @param mean the component's hyperparameters
 * @param sd the component's hyperparameters
 * @param length_scale the component's hyperparameters
 * @param nugget the component's hyperparameters: the nugget's sd
 * @param same_point 1 where two points are identical, else 0
 * @return (weight means at the experiments, their covariance)
 */
tuple(vector, matrix) component_weights(array[] vector points, array[] vector xt_runs, vector alpha,
                                        array[] vector xt_variance, matrix L_variance, real mean, real sd,
                                        array[] real length_scale, real nugget, matrix same_point) {
  matrix[size(xt_variance), size(points)] A
    = mdivide_left_tri_low(L_variance, gp_exp_quad_cov(xt_variance, points, sd, length_scale));
  return (mean + gp_exp_quad_cov(points, xt_runs, sd, length_scale) * alpha,
          gp_exp_quad_cov(points, sd, length_scale) + square(nugget) * same_point - crossprod(A));
}

/**
 * The runs' covariance factor and K^-1 (weights - mean) of every
 * component, from the weight GPs' hyperparameters (the joint program
 * samples them, so these change at every step).
 *
 * @param xt_runs (x, theta) of each run, unit cube
 * @param run_weights each run's component weights
 * @param mean per component, the weight GP's hyperparameters
 * @param sd per component, the weight GP's hyperparameters
 * @param length_scale per component, the weight GP's hyperparameters
 * @param nugget per component, the weight GP's hyperparameters
 * @return (per component, the runs' Cholesky factor; K^-1 (weights - mean), runs x components)
 */
tuple(array[] matrix, matrix) weight_gp_factors(array[] vector xt_runs, matrix run_weights, vector mean,
                                                vector sd, array[,] real length_scale, vector nugget) {
  int m = size(xt_runs);
  int n_comp = cols(run_weights);
  array[n_comp] matrix[m, m] L;
  matrix[m, n_comp] alpha;
  for (c in 1:n_comp) {
    L[c] = cholesky_decompose(emulator_run_cov(xt_runs, 1, sd[c], length_scale[c], nugget[c]));
    alpha[:, c] = mdivide_right_tri_low(mdivide_left_tri_low(L[c], run_weights[:, c] - mean[c])', L[c])';
  }
  return (L, alpha);
}

/**
 * Each experiment's emulator inputs (x_e, theta, theta_e).
 *
 * @param x each experiment's inputs, unit cube
 * @param theta_unit the shared theta on [0, 1]
 * @param theta_exp_unit each experiment's own theta on [0, 1]
 * @return one point per experiment
 */
array[] vector emulator_points(array[] vector x, vector theta_unit, array[] vector theta_exp_unit) {
  int n_exp = size(x);
  array[n_exp] vector[rows(x[1]) + rows(theta_unit) + rows(theta_exp_unit[1])] points;
  for (e in 1:n_exp) points[e] = append_row(x[e], append_row(theta_unit, theta_exp_unit[e]));
  return points;
}

/**
 * component_weights for every component, at each experiment's emulator
 * inputs (x_e, theta, theta_e).
 *
 * @param x each experiment's inputs; theta_unit, theta_exp_unit shared and
 *        per-experiment parameters, all on the unit cube
 * @param xt_runs every run; per component, K^-1 (weights - mean)
 * @param alpha every run; per component, K^-1 (weights - mean)
 * @param xt_variance the variance runs; per component, their covariance's Cholesky factor
 * @param L_variance the variance runs; per component, their covariance's Cholesky factor
 * @param emulator_mean stage 1, per component
 * @param emulator_sd stage 1, per component
 * @param emulator_length_scale stage 1, per component
 * @param emulator_nugget stage 1, per component
 * @param same_point 1 where two experiments' emulator inputs are identical, else 0
 * @param theta_unit every theta on [0, 1]; a functional theta's level
 * @param theta_exp_unit per-experiment parameters on the unit cube
 * @return (weight means, experiments x components; per component, the
 *         weights' covariance between experiments)
 */
tuple(matrix, array[] matrix) experiment_weights(array[] vector x, vector theta_unit, array[] vector theta_exp_unit,
                                                array[] vector xt_runs, matrix alpha,
                                                array[] vector xt_variance, array[] matrix L_variance,
                                                vector emulator_mean, vector emulator_sd,
                                                array[,] real emulator_length_scale, vector emulator_nugget,
                                                matrix same_point) {
  int n_exp = size(x);
  int n_comp = cols(alpha);
  array[n_exp] vector[rows(x[1]) + rows(theta_unit) + rows(theta_exp_unit[1])] points
    = emulator_points(x, theta_unit, theta_exp_unit);
  matrix[n_exp, n_comp] means;
  array[n_comp] matrix[n_exp, n_exp] covariances;
  for (c in 1:n_comp) {
    tuple(vector[n_exp], matrix[n_exp, n_exp]) w
      = component_weights(points, xt_runs, alpha[:, c], xt_variance, L_variance[c], emulator_mean[c],
                          emulator_sd[c], emulator_length_scale[c], emulator_nugget[c], same_point);
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
 * @param experiment_a rows a: their experiment,
 * @param components_a rows a: their experiment,
 * @param x_delta_a rows a: their experiment,
 *        the basis components at their index, (inputs, index) on the unit cube
 * @param experiment_b the same for rows b
 * @param components_b the same for rows b
 * @param x_delta_b the same for rows b
 * @param weight_cov per component, the weights' covariance between experiments
 * @param delta_sd the discrepancy (size 0: none)
 * @param delta_length_scale the discrepancy (size 0: none)
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
