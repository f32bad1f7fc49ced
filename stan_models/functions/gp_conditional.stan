/**
 * Mean of GP values at new points given observed values
 * (Rasmussen & Williams 2006, eq. 2.23).
 *
 * @param resid observed values minus their prior mean, size N
 * @param L_obs Cholesky factor of the covariance of resid (N x N)
 * @param K_cross covariance of the new values with the observed ones (P x N)
 * @return the conditional mean of the new values minus their prior mean, size P
 */
vector gp_conditional_mean(vector resid, matrix L_obs, matrix K_cross) {
  // K^-1 resid by two triangular solves: L \ resid, then L' \ (that)
  return K_cross * mdivide_right_tri_low(mdivide_left_tri_low(L_obs, resid)', L_obs)';
}

/**
 * One draw of GP values at new points given observed values
 * (Rasmussen & Williams 2006, eqs. 2.23-2.24).
 *
 * @param resid observed values minus their prior mean, size N
 * @param L_obs Cholesky factor of the covariance of resid (N x N)
 * @param K_cross covariance of the new values with the observed ones (P x N)
 * @param K_new prior covariance of the new values (P x P)
 * @return one draw of the new values minus their prior mean, size P
 */
vector gp_conditional_rng(vector resid, matrix L_obs, matrix K_cross,
                          matrix K_new) {
  int p = rows(K_new);
  matrix[rows(L_obs), p] A = mdivide_left_tri_low(L_obs, K_cross');
  vector[p] mean_new = A' * mdivide_left_tri_low(L_obs, resid);
  matrix[p, p] cov_new = K_new - crossprod(A);
  // 1e-8 keeps the factorisation stable where the conditional is near exact
  matrix[p, p] L_new = cholesky_decompose(add_diag(0.5 * (cov_new + cov_new'), 1e-8));
  return multi_normal_cholesky_rng(mean_new, L_new);
}

/**
 * One draw from a zero-mean GP prior, for prior predictive checks.
 *
 * @param K covariance of the values (P x P)
 * @return one draw, size P
 */
vector gp_prior_rng(matrix K) {
  int p = rows(K);
  return multi_normal_cholesky_rng(rep_vector(0, p), cholesky_decompose(add_diag(K, 1e-8)));
}
