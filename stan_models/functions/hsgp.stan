/**
 * Basis functions of a Hilbert-space approximate GP (Riutort-Mayol et al.
 * 2023, eqs. 10-13): on the box [-L_d, L_d] around the centre of the unit
 * cube, products over the inputs of the Laplacian's eigenfunctions
 * sin(pi j (x + L) / (2 L)) / sqrt(L). A GP is then Phi * weights, with
 * independent weights: O(N B) per gradient instead of O(N^3).
 * (Mirrored in Python by stancal.hsgp.basis, for the tests and the gap.)
 *
 * @param x points on the unit cube (prediction points may lie beyond it,
 *        inside the boundary)
 * @param index one row per basis function: its eigenfunction number per input
 * @param boundary L per input, in unit-range units about 0.5
 * @return basis matrix, size(x) x size(index)
 */
matrix hsgp_basis(array[] vector x, array[,] int index, vector boundary) {
  int n = size(x);
  int n_basis = size(index);
  matrix[n, n_basis] phi = rep_matrix(1, n, n_basis);
  for (d in 1:num_elements(boundary)) {
    vector[n] shifted = to_vector(x[:, d]) - 0.5 + boundary[d];
    for (b in 1:n_basis) {
      phi[:, b] = phi[:, b] .* sin(pi() * index[b, d] / (2 * boundary[d]) * shifted) / sqrt(boundary[d]);
    }
  }
  return phi;
}

/**
 * Standard deviation of each basis weight: the square root of the kernel's
 * spectral density at the basis function's frequency (Riutort-Mayol et al.
 * 2023, eqs. 1-2, ARD form). Squared exponential:
 *   S(w) = sd^2 (2 pi)^(D/2) prod(l) exp(-|l .* w|^2 / 2);
 * Matern 5/2 (nu = 5/2):
 *   S(w) = sd^2 2^D pi^(D/2) Gamma(nu + D/2) (2 nu)^nu / Gamma(nu)
 *          prod(l) (2 nu + |l .* w|^2)^-(nu + D/2).
 *
 * @param index eigenfunction numbers, one row per basis function
 * @param boundary L per input
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd marginal standard deviation of the GP
 * Each length scale is capped at the longest the boundary represents:
 * beyond it the approximate GP would shrink towards 0 (a second, false route
 * to a null discrepancy); capped, a longer length scale gives the smoothest
 * GP the basis holds, so the prior's long tail keeps its mass (a truncated
 * prior cut it off, and with it theta's trade-off with a nearly constant
 * discrepancy).
 *
 * @param length_scale one per input, fractions of the input's range
 * @param longest one per input: boundary / (the paper's c rule), same units
 * @return one sd per basis function
 */
vector hsgp_weight_sd(array[,] int index, vector boundary, int kernel_id, real marginal_sd,
                      array[] real length_scale, array[] real longest) {
  int n_dims = num_elements(boundary);
  vector[n_dims] capped;
  for (d in 1:n_dims) capped[d] = fmin(length_scale[d], longest[d]);
  vector[size(index)] scaled_sq = rep_vector(0, size(index));  // |l .* w|^2 per basis function
  for (d in 1:n_dims) {
    scaled_sq += square(capped[d] * pi() / (2 * boundary[d]) * to_vector(index[:, d]));
  }
  real log_scale = 2 * log(marginal_sd) + sum(log(capped));
  vector[size(index)] log_density;
  if (kernel_id == 2) {
    real nu = 2.5;
    log_density = log_scale + n_dims * log2() + 0.5 * n_dims * log(pi()) + lgamma(nu + 0.5 * n_dims)
                  + nu * log(2 * nu) - lgamma(nu) - (nu + 0.5 * n_dims) * log(2 * nu + scaled_sq);
  } else {
    log_density = log_scale + 0.5 * n_dims * log(2 * pi()) - 0.5 * scaled_sq;
  }
  return exp(0.5 * log_density);
}

/**
 * log N(r | 0, noise_var I + Phi diag(weight_sd^2) Phi'): the Hilbert-space
 * GP with its basis weights integrated out (Woodbury identity and matrix
 * determinant lemma). With Phi' Phi as data a gradient costs O(N B) for
 * Phi' r plus O(B^3), and the sampler sees only the few hyperparameters, not
 * B weights that the data pin far more tightly than their prior does.
 *
 * @param r residual y - mean
 * @param phi_t the basis transposed, B x N
 * @param phi_t_phi Phi' Phi, B x B
 * @param weight_sd prior sd of each basis weight (hsgp_weight_sd)
 * @param noise_var variance of the independent noise
 * @return log density
 */
real hsgp_marginal_lpdf(vector r, matrix phi_t, matrix phi_t_phi, vector weight_sd, real noise_var) {
  return hsgp_marginal_from_sums(dot_self(r), phi_t * r, num_elements(r), phi_t_phi, weight_sd, noise_var);
}

/**
 * hsgp_marginal_lpdf from the residual's sums alone: r' r and Phi' r. A
 * program whose mean is linear in a few precomputed columns gets both in
 * O(B K) for K columns, whatever N (modular_hsgp.stan).
 *
 * @param rtr r' r
 * @param phi_t_r Phi' r
 * @param n number of observations
 * @param phi_t_phi as in hsgp_marginal_lpdf
 * @param weight_sd as in hsgp_marginal_lpdf
 * @param noise_var as in hsgp_marginal_lpdf
 * @return log density
 */
real hsgp_marginal_from_sums(real rtr, vector phi_t_r, int n, matrix phi_t_phi, vector weight_sd,
                             real noise_var) {
  matrix[rows(phi_t_phi), rows(phi_t_phi)] L
    = cholesky_decompose(add_diag(quad_form_diag(phi_t_phi, weight_sd) / noise_var, 1));
  vector[rows(phi_t_phi)] v = mdivide_left_tri_low(L, weight_sd .* phi_t_r);
  return -0.5 * (rtr / noise_var - dot_self(v) / square(noise_var))
         - sum(log(diagonal(L))) - 0.5 * n * log(noise_var) - 0.5 * n * log(2 * pi());
}

/**
 * A draw of the basis weights from their conditional given the residual
 * (the posterior's weights for this draw of the hyperparameters):
 * w = weight_sd .* (A^-1 c / noise_var + L^-T z), A = L L' as in
 * hsgp_marginal_lpdf, c = weight_sd .* (Phi' r).
 *
 * @param r residual y - mean
 * @param phi_t as in hsgp_marginal_lpdf
 * @param phi_t_phi as in hsgp_marginal_lpdf
 * @param weight_sd as in hsgp_marginal_lpdf
 * @param noise_var as in hsgp_marginal_lpdf
 * @param z B standard normals
 * @return the weights, B
 */
vector hsgp_weights(vector r, matrix phi_t, matrix phi_t_phi, vector weight_sd, real noise_var, vector z) {
  matrix[rows(phi_t_phi), rows(phi_t_phi)] L
    = cholesky_decompose(add_diag(quad_form_diag(phi_t_phi, weight_sd) / noise_var, 1));
  vector[rows(phi_t_phi)] v = mdivide_left_tri_low(L, weight_sd .* (phi_t * r));
  return weight_sd .* mdivide_right_tri_low((v / noise_var + z)', L)';
}
