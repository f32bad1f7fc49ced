/**
 * Where two points are one: 1 where a_i == b_j, else 0. The emulator's
 * nugget, the part of the simulator a smooth GP misses, is one value at one
 * point and independent between points (Higdon et al. 2008).
 *
 * @param a the first points
 * @param b the second points
 * @return matrix of size(a) x size(b)
 */
matrix same_point(array[] vector a, array[] vector b) {
  matrix[size(a), size(b)] same = rep_matrix(0, size(a), size(b));
  for (i in 1:size(a)) {
    for (j in 1:size(b)) {
      if (max(abs(a[i] - b[j])) == 0) same[i, j] = 1;
    }
  }
  return same;
}

/**
 * same_point(x, x): where two of the points are one.
 *
 * @param x the points
 * @return matrix of size(x) x size(x)
 */
matrix same_point(array[] vector x) {
  return same_point(x, x);
}

/**
 * Which runs share one draw of the emulator's nugget: 1 on the diagonal, and
 * where two runs of a stochastic simulator (each with an intrinsic sd) are
 * replicates, at one setting (x, theta) and one fidelity level. The emulator
 * is of the simulator's mean, and its misfit to that mean is one value per
 * setting; the runs' own scatter about the mean is the intrinsic variance,
 * on the diagonal alone (stochastic kriging: Ankenman, Nelson & Staum 2010,
 * whose predictor on a setting's average sees the misfit whole and the
 * intrinsic variance divided by the replicates). A deterministic
 * simulator's runs (intrinsic sd 0) keep the nugget each on its own: there it
 * also absorbs round-off between exact duplicates, which a shared draw could
 * not.
 *
 * @param xt the runs' emulator inputs, (x, theta) on the unit cube
 * @param run_level each run's fidelity level
 * @param intrinsic_sd each run's intrinsic sd (0 = deterministic)
 * @return matrix of size(xt) x size(xt), ones and zeros
 */
matrix replicated_runs(array[] vector xt, array[] int run_level, vector intrinsic_sd) {
  int m = size(xt);
  matrix[m, m] same = same_point(xt);
  matrix[m, m] shared = identity_matrix(m);
  for (i in 1:m) {
    for (j in 1:m) {
      if (i != j && same[i, j] == 1 && intrinsic_sd[i] > 0 && intrinsic_sd[j] > 0
          && run_level[i] == run_level[j]) {
        shared[i, j] = 1;
      }
    }
  }
  return shared;
}

/**
 * The runs' own covariance beside the emulator's kernel: each run's level's
 * nugget, shared by replicates (replicated_runs), and each run's intrinsic
 * variance on the diagonal.
 *
 * @param replicated replicated_runs(...)
 * @param run_nugget each run's level's nugget sd
 * @param intrinsic_sd each run's intrinsic sd (0 = deterministic)
 * @return matrix of size rows(replicated)
 */
matrix run_own_cov(matrix replicated, vector run_nugget, vector intrinsic_sd) {
  return add_diag(diag_pre_multiply(run_nugget, diag_post_multiply(replicated, run_nugget)), square(intrinsic_sd));
}

/**
 * The covariance of one GP emulator's runs (emulator.stan): the kernel over
 * (x, theta), the runs' own covariance (run_own_cov: the nugget where runs
 * share one, and each run's intrinsic variance), and the jitter. With no
 * replicates, emulator_run_cov (gp_kernels.stan) plus the intrinsic variance.
 *
 * @param xt_sim emulator inputs of the runs, (x, theta) on the unit cube
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param emulator_sd emulator GP hyperparameters
 * @param emulator_length_scale emulator GP hyperparameters
 * @param emulator_nugget standard deviation of the runs' nugget
 * @param replicated replicated_runs(...)
 * @param intrinsic_sd each run's intrinsic sd (0 = deterministic)
 * @return covariance matrix, size(xt_sim) x size(xt_sim)
 */
matrix emulator_run_cov(array[] vector xt_sim, int kernel_id, real emulator_sd,
                        array[] real emulator_length_scale, real emulator_nugget, matrix replicated,
                        vector intrinsic_sd) {
  return add_jitter(ard_cov(xt_sim, kernel_id, emulator_sd, emulator_length_scale)
                    + run_own_cov(replicated, rep_vector(emulator_nugget, size(xt_sim)), intrinsic_sd),
                    square(emulator_sd));
}
