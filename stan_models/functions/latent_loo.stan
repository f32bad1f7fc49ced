/**
 * Leave-one-out quantities of the latent-GP programs (koh_latent*.stan).
 * PSIS-LOO on log p(y_i | delta_i, parameters) fails there: each latent
 * delta_i is pinned by its own y_i, so leaving y_i out moves the posterior
 * far (Pareto k above 0.7 at most points). The discrepancy at the left-out
 * point is integrated out instead, over its GP conditional given the others
 * (Vehtari, Mononen, Tolvanen, Sivula & Winther 2016, "Bayesian leave-one-out
 * cross-validation approximations for Gaussian latent variable models",
 * JMLR 17, section 3.3):
 *   p(y_i | delta_-i, parameters) = int p(y_i | eta_i + d) N(d | m_i, s_i^2) dd.
 * With Q = K^-1 (one inversion): s_i^2 = 1 / Q_ii, m_i = delta_i - (Q delta)_i / Q_ii.
 * Needs observation_model.stan.
 */

/**
 * Gauss-Hermite rule for E[g(u)], u ~ N(0, 1), from the eigenvalues and
 * eigenvectors of the Jacobi matrix (Golub & Welsch 1969).
 *
 * @param n number of nodes
 * @return (nodes, weights); the weights sum to 1
 */
tuple(vector, vector) normal_quadrature(int n) {
  matrix[n, n] jacobi = rep_matrix(0, n, n);
  for (k in 1:(n - 1)) {
    jacobi[k, k + 1] = sqrt(k);
    jacobi[k + 1, k] = sqrt(k);
  }
  return (eigenvalues_sym(jacobi), square(eigenvectors_sym(jacobi)[1])');
}

/**
 * First and second derivatives in eta of log p(y | eta) for the count and
 * binomial observation models; all three are concave in eta.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param eta linear predictor on the model scale
 * @param phi negative binomial precision, Var = mu + mu^2 / phi (else unused)
 * @param y the count (poisson, negbinomial) or successes (binomial)
 * @param trials binomial trials (unused otherwise)
 * @return [d/deta, d2/deta2] of log p(y | eta)
 */
vector count_log_lik_derivatives(int likelihood_id, real eta, real phi, int y, int trials) {
  if (likelihood_id == 2) {
    real mu = exp(eta);
    return [y - mu, -mu]';
  }
  if (likelihood_id == 3) {
    real mu = exp(eta);
    return [y - (y + phi) * mu / (mu + phi), -(y + phi) * mu * phi / square(mu + phi)]';
  }
  real p = inv_logit(eta);
  return [y - trials * p, -trials * p * (1 - p)]';
}

/**
 * log of the integral over d of p(y | eta + d) N(d | m, s^2) for one count or
 * binomial observation, by Gauss-Hermite quadrature centred and scaled at the
 * Laplace approximation of the integrand (adaptive quadrature, Liu & Pierce
 * 1994): plain quadrature misses a likelihood much narrower than s, which is
 * the rule for large counts.
 *
 * @param rule normal_quadrature(n)
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param eta linear predictor on the model scale
 * @param m mean of the normal the discrepancy at the point has
 * @param s sd of that normal
 * @param phi negative binomial precision, Var = mu + mu^2 / phi (else unused)
 * @param y the count (poisson, negbinomial) or successes (binomial)
 * @param trials binomial trials (unused otherwise)
 * @return log of the integral of p(y | eta + delta) N(delta | m, s^2)
 */
real integrated_count_log_lik(int likelihood_id, real eta, real m, real s, real phi, int y, int trials,
                              tuple(vector, vector) rule) {
  real d = m;
  for (step in 1:50) {  // damped Newton on a strictly concave function
    vector[2] l = count_log_lik_derivatives(likelihood_id, eta + d, phi, y, trials);
    real move = fmin(fmax((l[1] - (d - m) / square(s)) / (l[2] - inv_square(s)), -1), 1);
    d -= move;
    if (abs(move) < 1e-10) break;
  }
  real sigma = inv_sqrt(inv_square(s) - count_log_lik_derivatives(likelihood_id, eta + d, phi, y, trials)[2]);
  int q = rows(rule.1);
  vector[q] d_nodes = d + sigma * rule.1;
  vector[q] log_lik = observation_log_lik(likelihood_id, eta + d_nodes, 1, phi, rep_vector(0, q),
                                          rep_array(y, q), rep_array(trials, q), rep_array(0, q),
                                          rep_vector(0, q), rep_vector(0, q));
  return log(sigma / s)
         + log_sum_exp(log(rule.2) + log_lik - 0.5 * square((d_nodes - m) / s) + 0.5 * square(rule.1));
}

/**
 * Pointwise log p(y_i | delta_-i, parameters) and E(y_i | delta_-i, parameters),
 * both in original units, with delta_i integrated out: in closed form for
 * Gaussian outputs (censored or not: the noise sd grows to sqrt(noise_sd^2 + s_i^2)),
 * by integrated_count_log_lik otherwise.
 *
 * @param eta_rest the linear predictor without the discrepancy GP, model scale
 * @param delta the latent discrepancy at the points, model scale
 * @param L_delta Cholesky factor of its prior covariance; 0 x 0 without a discrepancy
 * @param rule normal_quadrature(n)
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param noise_sd observation noise sd, standardised units
 * @param phi negative binomial precision, Var = mu + mu^2 / phi (else unused)
 * @param y_real gaussian: standardised output (unused where censored or not gaussian)
 * @param y_int counts or successes (unused for gaussian)
 * @param trials binomial trials (unused otherwise)
 * @param censoring 0 = observed, 1 = left, 2 = right, 3 = interval, per point
 * @param lower_bound censoring lower bounds, standardised like y_real
 * @param upper_bound censoring upper bounds, standardised like y_real
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return (log_lik, loo_mean)
 */
tuple(vector, vector) latent_loo(int likelihood_id, vector eta_rest, vector delta, matrix L_delta,
                                 real noise_sd, real phi, vector y_real, array[] int y_int,
                                 array[] int trials, array[] int censoring, vector lower_bound,
                                 vector upper_bound, real y_center, real y_scale,
                                 tuple(vector, vector) rule) {
  int n = rows(eta_rest);
  vector[n] m = rep_vector(0, n);
  vector[n] s = rep_vector(0, n);
  if (cols(L_delta) > 0) {
    matrix[n, n] precision = chol2inv(L_delta);
    vector[n] c = diagonal(precision);
    m = delta - (precision * delta) ./ c;
    s = inv_sqrt(c);
  }
  vector[n] log_lik;
  vector[n] loo_mean;
  for (i in 1:n) {
    if (likelihood_id == 1 || s[i] == 0) {
      log_lik[i] = observation_log_lik(likelihood_id, [eta_rest[i] + m[i]]',
                                       sqrt(square(noise_sd) + square(s[i])), phi, y_real[i:i],
                                       y_int[i:i], trials[i:i], censoring[i:i], lower_bound[i:i],
                                       upper_bound[i:i])[1];
    } else {
      log_lik[i] = integrated_count_log_lik(likelihood_id, eta_rest[i], m[i], s[i], phi, y_int[i],
                                            trials[i], rule);
    }
    loo_mean[i] = dot_product(rule.2, response_scale(likelihood_id, eta_rest[i] + m[i] + s[i] * rule.1,
                                                     y_center, y_scale));
  }
  return (log_lik_original_units(likelihood_id, log_lik, censoring, y_scale), loo_mean);
}

/**
 * The generated quantities at the physical points that both latent programs
 * share, original units.
 *
 * @param eta_rest the linear predictor without the discrepancy GP, model scale
 * @param delta the latent discrepancy GP at the points, model scale
 * @param L_delta Cholesky factor of its prior covariance; 0 x 0 without a discrepancy
 * @param other arguments as in observation_log_lik and latent_loo
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param sd_obs gaussian observation sd (else unused)
 * @param precision negative binomial precision (else unused)
 * @param y_real gaussian: standardised output (unused where censored or not gaussian)
 * @param y_int counts or successes (unused for gaussian)
 * @param trials binomial trials (unused otherwise)
 * @param censoring 0 = observed, 1 = left, 2 = right, 3 = interval, per point
 * @param lower_bound censoring lower bounds, standardised like y_real
 * @param upper_bound censoring upper bounds, standardised like y_real
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @param rule normal quadrature nodes and weights (normal_quadrature)
 * @return (log p(y_i | delta_-i, parameters), E(y_i | delta_-i, parameters), replicated data)
 */
tuple(vector, vector, vector) latent_observation_quantities_rng(
    int likelihood_id, vector eta_rest, vector delta, matrix L_delta, real sd_obs, real precision,
    vector y_real, array[] int y_int, array[] int trials, array[] int censoring, vector lower_bound,
    vector upper_bound, real y_center, real y_scale, tuple(vector, vector) rule) {
  tuple(vector[rows(delta)], vector[rows(delta)]) loo = latent_loo(
    likelihood_id, eta_rest, delta, L_delta, sd_obs, precision, y_real, y_int, trials, censoring,
    lower_bound, upper_bound, y_center, y_scale, rule);
  return (loo.1, loo.2,
          observations_original_units(
            likelihood_id, observation_rng(likelihood_id, eta_rest + delta, sd_obs, precision, trials),
            y_center, y_scale));
}
