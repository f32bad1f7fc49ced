/**
 * Exact leave-one-out log predictive densities of a multivariate normal,
 * log p(y_i | y_-i), for PSIS-LOO on a non-factorized GP likelihood
 * (Burkner, Gabry & Vehtari 2021, "Efficient leave-one-out cross-validation
 * for Bayesian non-factorized normal and Student-t models", eqs. 7-8).
 *
 * @param resid observed values minus their mean, size N
 * @param L Cholesky factor of their covariance (N x N)
 * @return the N leave-one-out log densities
 */
vector mvn_loo_log_lik(vector resid, matrix L) {
  int n = rows(resid);
  matrix[n, n] K_inv = chol2inv(L);
  vector[n] g = K_inv * resid;
  vector[n] c = diagonal(K_inv);
  return -0.5 * log(2 * pi()) + 0.5 * log(c) - 0.5 * square(g) ./ c;
}

/**
 * Leave-one-out predictive means of a multivariate normal,
 * E(resid_i | resid_-i) = resid_i - [K^-1 resid]_i / [K^-1]_ii
 * (same reference, eq. 7): held-out predictions without refitting.
 *
 * @param resid observed values minus their mean, size N
 * @param L Cholesky factor of their covariance (N x N)
 * @return the N leave-one-out means of resid
 */
vector mvn_loo_mean(vector resid, matrix L) {
  matrix[rows(resid), rows(resid)] K_inv = chol2inv(L);
  return resid - (K_inv * resid) ./ diagonal(K_inv);
}
