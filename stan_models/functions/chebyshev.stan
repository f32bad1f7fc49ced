/**
 * Tensor Chebyshev polynomials on the unit cube: for each parameter q,
 * T_0 .. T_degree[q] at 2 theta_q - 1, multiplied out over the parameters
 * with the first parameter's index varying slowest. modular_hsgp.stan
 * interpolates the emulator mean in theta with them.
 * (Mirrored in Python by stancal.scalable_emulator.chebyshev_basis.)
 *
 * @param theta_unit parameters on the unit cube
 * @param degree polynomial degree per parameter
 * @return prod(degree + 1) basis values
 */
vector chebyshev_tensor_basis(vector theta_unit, array[] int degree) {
  int n_params = num_elements(theta_unit);
  int n_basis = 1;
  for (q in 1:n_params) n_basis *= degree[q] + 1;
  vector[n_basis] out = rep_vector(1, n_basis);
  int stride = n_basis;
  for (q in 1:n_params) {
    int n_q = degree[q] + 1;
    real s = 2 * theta_unit[q] - 1;
    vector[n_q] T;
    T[1] = 1;
    if (n_q > 1) T[2] = s;
    for (k in 3:n_q) T[k] = 2 * s * T[k - 1] - T[k - 2];
    stride = stride %/% n_q;
    for (g in 1:n_basis) out[g] *= T[((g - 1) %/% stride) % n_q + 1];
  }
  return out;
}
