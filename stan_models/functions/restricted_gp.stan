/**
 * Restricted GP discrepancies (review section 6): a GP delta conditioned on
 * linear functionals A' delta(U) at nodes U, for an identifiable theta.
 * The restricted covariance is K_ab - V_a' V_b with V = L_T \ (A' K_U.),
 * T = A' K_UU A (+ a ridge), L_T its Cholesky factor.
 *
 * Orthogonal GP (Plumlee 2017, eq. 12): U = quadrature nodes on the input box,
 *   A = diag(w) * df/dtheta, so that int delta(x) df/dtheta_j(x) dx = 0 a priori
 *   and theta targets the L2 projection.
 * Scaled GP (S-GaSP, Gu & Wang 2018): U = the physical points, A = I, ridge
 *   sd^2 N / lambda: delta given a penalised mean square over the points,
 *   K - K (K + sd^2 N / lambda I)^-1 K.
 */

/**
 * Cholesky factor of T = A' K_UU A + ridge * I.
 * @param ridge 0 for the orthogonal GP, sd^2 N / lambda for the scaled GP;
 *   the jitter (add_jitter) covers a theta without influence, which makes T singular
 * @param K_UU prior covariance of the nodes U
 * @param A U x functionals map of the restriction
 * @return lower Cholesky factor L_T, functionals x functionals
 */
matrix restriction_cholesky(matrix K_UU, matrix A, real ridge) {
  matrix[cols(A), cols(A)] T = quad_form_sym(K_UU, A);
  return cholesky_decompose(add_jitter(add_diag(T, ridge), mean(diagonal(T))));
}

/**
 * V_a = L_T \ (A' K_Ua): the restricted covariance is K_ab - V_a' V_b.
 * @param K_Ua prior covariance of the nodes U with the points a (U x a)
 * @param A U x functionals map of the restriction
 * @param L_T Cholesky factor of T (restriction_cholesky)
 * @return V_a, functionals x a
 */
matrix restriction_factor(matrix K_Ua, matrix A, matrix L_T) {
  return mdivide_left_tri_low(L_T, A' * K_Ua);
}

/**
 * The discrepancy GP's prior covariances at the points x and x_new, restricted
 * by the functionals A' delta(U) when A has rows (unrestricted when it has
 * none): built once for the model block and generated quantities.
 *
 * @param x the points (the physical points)
 * @param x_new other points (the prediction points; none in the model block)
 * @param x_U the nodes U (empty when unrestricted)
 * @param A U x functionals map of the restriction (0 rows: unrestricted)
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd the GP's marginal sd
 * @param length_scale the GP's length scales, one per input
 * @param ridge see restriction_cholesky
 * @return covariance of x (n x n), of x_new with x (p x n), of x_new (p x p)
 */
tuple(matrix, matrix, matrix) restricted_gp_cov(array[] vector x, array[] vector x_new, array[] vector x_U,
                                                matrix A, int kernel_id, real marginal_sd,
                                                array[] real length_scale, real ridge) {
  int n = size(x);
  int p = size(x_new);
  matrix[n, n] K = ard_cov(x, kernel_id, marginal_sd, length_scale);
  matrix[p, n] K_cross = ard_cross_cov(x_new, x, kernel_id, marginal_sd, length_scale);
  matrix[p, p] K_new = ard_cov(x_new, kernel_id, marginal_sd, length_scale);
  if (rows(A) > 0) {
    matrix[cols(A), cols(A)] L_T = restriction_cholesky(
      ard_cov(x_U, kernel_id, marginal_sd, length_scale), A, ridge);
    matrix[cols(A), n] V = restriction_factor(ard_cross_cov(x_U, x, kernel_id, marginal_sd, length_scale), A, L_T);
    matrix[cols(A), p] V_new = restriction_factor(
      ard_cross_cov(x_U, x_new, kernel_id, marginal_sd, length_scale), A, L_T);
    K -= crossprod(V);
    K_cross -= V_new' * V;
    K_new -= crossprod(V_new);
  }
  return (K, K_cross, K_new);
}
