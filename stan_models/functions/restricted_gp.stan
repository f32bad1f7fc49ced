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
 */
matrix restriction_cholesky(matrix K_UU, matrix A, real ridge) {
  matrix[cols(A), cols(A)] T = quad_form_sym(K_UU, A);
  return cholesky_decompose(add_jitter(add_diag(T, ridge), mean(diagonal(T))));
}

/**
 * V_a = L_T \ (A' K_Ua): the restricted covariance is K_ab - V_a' V_b.
 * @param K_Ua prior covariance of the nodes U with the points a (U x a)
 */
matrix restriction_factor(matrix K_Ua, matrix A, matrix L_T) {
  return mdivide_left_tri_low(L_T, A' * K_Ua);
}
