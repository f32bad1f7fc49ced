/**
 * The latent discrepancy GP partially non-centred, with the data's
 * information per point (Papaspiliopoulos, Roberts & Skold 2003, 2007;
 * Christensen, Roberts & Skold 2006, "Robust Markov chain Monte Carlo methods
 * for spatial generalized linear mixed models", JCGS 15:1-17).
 *
 * The likelihood of each point is approximated once, from the data alone, by
 * a normal on the model (link) scale: eta_i ~ N(pseudo_i, 1 / w_i), w_i the
 * information per point (stancal.numerics.parametrization). Given the rest of
 * the linear predictor m = g(f(x, theta)) + h' beta, delta's posterior is then
 * about N(C W (pseudo - m), C), with C = (K^-1 + W)^-1. The sampler's
 * parameters z are its standardised values:
 *   delta = C W (pseudo - m) + A z,   A A' = C.
 * In the directions where the data dominate the GP prior, delta moves with
 * theta so that eta stays where the data put it (centred there: no ridge
 * between theta and delta); where the prior dominates, delta = L z
 * (non-centred there: no funnel with the GP's hyperparameters). w = 0 is the
 * non-centred form exactly. The model is unchanged: only the parametrisation
 * uses the approximation, so the posterior is exact whatever w and pseudo are.
 *
 * With K = L L' and I + L' W L = R R': A = L R^-T, and for v = A' W r + z,
 * delta = L u with u = R^-T v. The GP prior's log density of delta plus the
 * log Jacobian log|A| is then -u'u / 2 - sum(log diag R) (up to a constant).
 */

/**
 * The discrepancy's values from the sampler's standardised parameters, with
 * the GP prior's log density and the transform's log Jacobian added to the
 * target.
 *
 * @param z the sampled standard normals, one per point
 * @param rest the linear predictor without the discrepancy, g(f) + h' beta, model scale
 * @param pseudo the data's value per point on the model scale (log(y + 1/2) for counts)
 * @param information the data's information per point on the model scale (>= 0)
 * @param x the discrepancy inputs of the points
 * @param kernel_id 1 = squared exponential, 2 = Matern 5/2
 * @param marginal_sd the GP's marginal sd
 * @param length_scale the GP's length scales, one per input
 * @return the discrepancy's values at the points, model scale
 */
vector latent_gp_partial_lp(vector z, vector rest, vector pseudo, vector information, array[] vector x,
                            int kernel_id, real marginal_sd, array[] real length_scale) {
  int n = rows(z);
  matrix[n, n] L = latent_gp_cholesky(x, kernel_id, marginal_sd, length_scale);
  matrix[n, n] R = cholesky_decompose(add_diag(crossprod(diag_pre_multiply(sqrt(information), L)), 1));
  // v = A' W r + z, A' = R^-1 L'
  vector[n] v = mdivide_left_tri_low(R, L' * (information .* (pseudo - rest))) + z;
  vector[n] u = mdivide_right_tri_low(v', R)';  // R^-T v
  target += -0.5 * dot_self(u) - sum(log(diagonal(R)));
  return L * u;
}
