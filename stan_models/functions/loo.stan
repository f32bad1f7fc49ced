/**
 * Exact leave-one-out predictive densities and means of a multivariate
 * normal, for PSIS-LOO on a non-factorized GP likelihood and for held-out
 * predictions without refitting (Burkner, Gabry & Vehtari 2021, "Efficient
 * leave-one-out cross-validation for Bayesian non-factorized normal and
 * Student-t models", eqs. 7-8): with g = K^-1 resid and c = diag(K^-1),
 *   log p(resid_i | resid_-i) = -log(2 pi) / 2 + log(c_i) / 2 - g_i^2 / (2 c_i),
 *   E(resid_i | resid_-i) = resid_i - g_i / c_i.
 * One inversion of K serves both.
 *
 * @param resid observed values minus their mean, size N
 * @param L Cholesky factor of their covariance (N x N)
 * @return (the N leave-one-out log densities, the N leave-one-out means of resid)
 */
tuple(vector, vector) mvn_loo(vector resid, matrix L) {
  int n = rows(resid);
  matrix[n, n] K_inv = chol2inv(L);
  vector[n] g = K_inv * resid;
  vector[n] c = diagonal(K_inv);
  return (-0.5 * log(2 * pi()) + 0.5 * log(c) - 0.5 * square(g) ./ c, resid - g ./ c);
}
