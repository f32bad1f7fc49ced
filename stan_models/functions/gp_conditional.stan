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
 * (Rasmussen & Williams 2006, eqs. 2.23-2.24), from given standard normals.
 *
 * @param resid observed values minus their prior mean, size N
 * @param L_obs Cholesky factor of the covariance of resid (N x N)
 * @param K_cross covariance of the new values with the observed ones (P x N)
 * @param K_new prior covariance of the new values (P x P)
 * @param z standard normals, size P
 * @return one draw of the new values minus their prior mean, size P
 */
vector gp_conditional_draw(vector resid, matrix L_obs, matrix K_cross, matrix K_new, vector z) {
  int p = rows(K_new);
  if (p == 0) return rep_vector(0, 0);
  matrix[rows(L_obs), p] A = mdivide_left_tri_low(L_obs, K_cross');
  vector[p] mean_new = A' * mdivide_left_tri_low(L_obs, resid);
  matrix[p, p] cov_new = K_new - crossprod(A);
  // symmetrised against round-off; the jitter covers a conditional that is near exact
  return mean_new + cholesky_decompose(add_jitter(0.5 * (cov_new + cov_new'), mean(diagonal(K_new)))) * z;
}

/**
 * One draw from a zero-mean GP prior, for prior predictive checks.
 *
 * @param K covariance of the values (P x P)
 * @param z standard normals, size P
 * @return one draw, size P
 */
vector gp_prior_draw(matrix K, vector z) {
  return cholesky_decompose(add_jitter(K, mean(diagonal(K)))) * z;
}

/**
 * n fresh standard normals from Stan's RNG (none for n = 0: Stan Math's
 * vectorised normal_rng crashes the process on an empty vector).
 *
 * @param n the number of values
 * @return n standard normals from Stan's RNG
 */
vector std_normals_rng(int n) {
  if (n == 0) {
    return rep_vector(0, 0);
  }
  return to_vector(normal_rng(rep_vector(0, n), 1));
}

/**
 * Standard normals for the draws at the prediction points: column k of the
 * given ones, or fresh ones from Stan's RNG when none are given (rows = 0).
 * stancal gives them when it reruns generated quantities under PyStan,
 * because httpstan seeds the RNG with 0 on every call: every parameter draw
 * would get the same normals, and the bands would be too narrow.
 *
 * @param given P x columns standard normals, or 0 x columns
 * @param k the column for this draw
 * @param n the number of values needed (P)
 * @return n standard normals
 */
vector prediction_normals_rng(matrix given, int k, int n) {
  if (rows(given) == 0) {
    return std_normals_rng(n);
  }
  return given[:, k];
}
