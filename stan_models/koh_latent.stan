// Kennedy-O'Hagan calibration with a cheap simulator written in Stan and a
// latent GP discrepancy, for what the Gaussian program koh.stan cannot
// integrate out (sampled centred, non-centred or partially non-centred by the
// data flag delta_centred, functions/latent_gp.stan and latent_partial.stan;
// stancal chooses from the data):
//   g(E[y_i]) = g(f(x_i, theta(x_i))) + h(x_i, z_i)' beta + delta(x_i, z_i)
// with optional mean terms h (a candidate unmodelled effect, as in koh.stan):
// - non-Gaussian outputs (review section 8.1.4; Grosskopf et al. 2021):
//   poisson and negative binomial counts with a log link, binomial successes
//   with a logit link; f is the mean on the response scale;
// - censored Gaussian outputs (section 8.1.5; Cao et al. 2018): left, right
//   or interval censoring per point, through lcdf/lccdf terms;
// - functional calibration parameters theta_j(x) (section 8.2), see
//   functions/functional_theta.stan; no discrepancy by default.
// Gaussian outputs are standardised inside; a link scale is not.
// log_lik is log p(y_i | delta_-i, parameters), with the discrepancy at the
// left-out point integrated out (functions/latent_loo.stan), for PSIS-LOO.
functions {
#include simulator.stan
#include simulator_output.stan
#include gp_kernels.stan
#include gp_conditional.stan
#include latent_gp.stan
#include latent_partial.stan
#include observation_model.stan
#include latent_loo.stan
#include functional_theta.stan
#include latent_koh.stan
#include priors.stan
#include scaling.stan
#include given_normals.stan
}
data {
  int<lower=1> N;                       // number of physical observations
  int<lower=1> D;                       // number of simulator inputs
  int<lower=1> D_delta;                 // number of discrepancy inputs: simulator inputs, then covariates
  int<lower=1> Q;                       // number of calibration parameters
  matrix[N, D] X;                       // simulator inputs of the physical points, original units
  array[N] vector[D_delta] x_delta;     // discrepancy inputs of the physical points, scaled to [0, 1]
  int<lower=1, upper=4> likelihood_id;  // 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
  vector[N] y_real;                     // gaussian: output, standardised (0 where censored or not gaussian)
  array[N] int<lower=0> y_int;          // poisson, negbinomial: counts; binomial: successes (else 0)
  array[N] int<lower=0> trials;         // binomial: number of trials (else 0)
  array[N] int<lower=0, upper=3> censoring;  // 0 = observed, 1 = left, 2 = right, 3 = interval
  vector[N] lower_bound;                // censoring bounds, standardised like y_real (used where censored)
  vector[N] upper_bound;                // see lower_bound
  real y_center;                        // gaussian: original-scale y = y_center + y_scale * y (unused otherwise)
  real<lower=0> y_scale;                // gaussian: see y_center (unused otherwise)
  vector[Q] theta_lower;                // lower bounds of theta, original units (uniform prior)
  vector<lower=theta_lower>[Q] theta_upper;  // upper bounds of theta, original units
  int<lower=0, upper=1> use_discrepancy;     // 1 = GP discrepancy on the link scale, 0 = none
  int<lower=0> H;                       // number of discrepancy mean terms (0 = zero mean)
  matrix[N, H] h;                       // mean terms at the physical points, scaled to unit RMS
  vector<lower=0>[H] beta_prior_sd;     // prior sd of each coefficient, model-scale units
  int<lower=1, upper=2> kernel_id;      // kernel of every GP: 1 = squared exponential, 2 = Matern 5/2
  int<lower=0, upper=Q> F;              // number of functional theta
  array[Q] int<lower=0, upper=F> functional_slot;  // 0 = scalar theta, k = the k-th functional one
  int<lower=0> D_fun;                   // number of inputs the functional theta vary over
  int<lower=0> N_fun;                   // number of distinct values of those inputs among the physical points
  array[N_fun] vector[D_fun] x_fun;     // the distinct values, scaled to [0, 1]
  array[F > 0 ? N : 0] int<lower=1, upper=N_fun> fun_point;  // which of them each physical point has
  int<lower=0, upper=1> functional_centred;  // 1 = sample theta(x)'s logit values, 0 = their standard normals
  int<lower=0, upper=2> delta_centred;  // 1 = sample the discrepancy's values, 0 = their standard normals,
                                        // 2 = partially non-centred with the data's information (latent_partial.stan)
  vector[N] delta_pseudo;               // delta_centred 2: the data's value per point, model scale
  vector<lower=0>[N] delta_information; // delta_centred 2: the data's information per point, model scale
  int<lower=0> G;                       // number of grid points for the theta(x) curves
  array[G] vector[D_fun] x_fun_grid;    // the grid, scaled like x_fun
  int<lower=0, upper=1> prior_only;     // 1 = ignore y: draws from the prior
  int<lower=0> P;                       // number of prediction points
  matrix[P, D] X_new;                   // simulator inputs of the prediction points, original units
  array[P] vector[D_delta] x_delta_new; // discrepancy inputs of the prediction points, scaled to [0, 1]
  array[P] vector[D_fun] x_fun_new;     // functional inputs of the prediction points, scaled like x_fun
  matrix[P, H] h_new;                   // mean terms at the prediction points, scaled like h
  array[P] int<lower=0> trials_new;     // binomial: trials of a new observation at each prediction point
#include functional_prediction_normals_data.stan
}
transformed data {
  // for the leave-one-out densities with the left-out discrepancy integrated out
  tuple(vector[20], vector[20]) loo_rule = normal_quadrature(20);
  check_given_normals(P_normals, P);
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;   // theta on [0, 1]; a functional theta's level
  array[likelihood_id == 1] real<lower=0> noise_sd;       // gaussian, standardised units
  array[likelihood_id == 3] real<lower=0> inv_sqrt_phi;   // negbinomial overdispersion
  array[use_discrepancy] real<lower=0> delta_sd;          // model-scale units
  array[use_discrepancy ? D : 0] real<lower=0> delta_input_length_scale;  // simulator inputs: fraction of input range
  array[use_discrepancy ? D_delta - D : 0] real<lower=0> delta_relevance;  // covariates: inverse length scale
  vector[use_discrepancy ? N : 0] delta_raw;              // the discrepancy (centred) or its standard normals
                                                          // (partial: the standardised z of latent_partial.stan)
  vector[H] beta;                                         // mean-term coefficients, model-scale units
  vector<lower=0>[F] theta_function_sd;                   // logit scale
  array[F] vector<lower=0>[D_fun] theta_function_length_scale;  // fraction of input range
  matrix[N_fun, F] theta_function_raw;    // its logit at x_fun (centred) or their standard normals
}
transformed parameters {
  // logit of functional theta (unit scale) at x_fun
  matrix[N_fun, F] theta_function_logit = functional_logit_values(
    theta_function_raw, functional_centred, theta_unit, functional_slot, x_fun, kernel_id, theta_function_sd,
    theta_function_length_scale);
  // the discrepancy's length scales over all its inputs: a covariate's is 1 / relevance
  array[use_discrepancy ? D_delta : 0] real delta_length_scale
    = discrepancy_length_scales(delta_input_length_scale, delta_relevance);
  // theta at each physical point (one row when none is functional), original units
  matrix[F > 0 ? N : 1, Q] theta_points = theta_rows_original(
    theta_unit_rows(theta_unit, functional_slot, theta_function_logit[fun_point]),
    theta_lower, theta_upper);
  vector[Q] theta;                      // scalar theta; a functional one's mean over the points
  for (j in 1:Q) theta[j] = mean(theta_points[:, j]);
  // the linear predictor without the discrepancy GP, model scale: the simulator runs once per gradient
  // (the partial form, the likelihood and generated quantities all use it)
  vector[N] eta_rest = simulator_model_scale(likelihood_id, simulator_at_rows(X, theta_points, 0, 1), X,
                                             y_center, y_scale) + h * beta;
  vector[N] delta = rep_vector(0, N);   // discrepancy at the physical points, model scale
  if (use_discrepancy && delta_centred == 2) {
    // its GP prior and the transform's Jacobian enter the target here (latent_partial.stan)
    delta = latent_gp_partial_lp(delta_raw, eta_rest, delta_pseudo, delta_information, x_delta, kernel_id,
                                 delta_sd[1], delta_length_scale);
  } else if (use_discrepancy) {
    delta = latent_gp_values(delta_raw, delta_centred, x_delta, kernel_id, delta_sd[1], delta_length_scale);
  }
}
model {
  // theta_unit is uniform on [0, 1]: the bounds are the prior support.
  noise_sd ~ observation_noise_sd();                 // half-normal(0, 1)
  inv_sqrt_phi ~ overdispersion();                   // half-normal(0, 1)
  delta_sd ~ discrepancy_sd();                       // half-normal(0, 0.5)
  delta_input_length_scale ~ discrepancy_length_scale();  // inverse gamma(3, 1)
  delta_relevance ~ covariate_relevance();           // half-normal(0, 2)
  // the discrepancy's GP (centred) or its standard normals (non-centred); the partially non-centred
  // form adds its prior and Jacobian in transformed parameters
  if (use_discrepancy && delta_centred < 2) {
    target += latent_gp_prior_lupdf(delta_raw | delta_centred, x_delta, kernel_id, delta_sd[1],
                                    delta_length_scale);
  }
  beta ~ normal(0, beta_prior_sd);
  theta_function_sd ~ functional_sd();              // half-normal(0, 1.5)
  for (k in 1:F) theta_function_length_scale[k] ~ functional_length_scale();  // inverse gamma(3, 1)
  // the functional theta's GP (centred) or its standard normals (non-centred)
  target += functional_theta_prior_lupdf(theta_function_logit | theta_function_raw, functional_centred, theta_unit,
                                         functional_slot, x_fun, kernel_id, theta_function_sd,
                                         theta_function_length_scale);
  if (!prior_only) {
    target += sum(observation_log_lik(
      likelihood_id, eta_rest + delta, observation_sd(likelihood_id, noise_sd),
      negbinomial_precision(likelihood_id, inv_sqrt_phi),
      y_real, y_int, trials, censoring, lower_bound, upper_bound));
  }
}
generated quantities {
  array[likelihood_id == 1] real noise_sd_original;
  array[likelihood_id == 3] real phi;   // negbinomial precision: Var = mu + mu^2 / phi
  array[use_discrepancy] real delta_sd_original;
  vector[N] log_lik;      // log p(y_i | delta_-i, parameters), delta_i integrated out; original units
  vector[N] y_loo_mean;   // E(y_i | delta_-i, parameters), original units
  vector[N] y_rep;        // replicated data, original units
  vector[N] delta_gp;     // discrepancy GP at the physical points, original units (link scale)
  matrix[G, F] theta_function_grid;  // functional theta on the grid, original units
  vector[P] f_new;        // simulator mean at the prediction points, response scale
  vector[P] delta_new;    // discrepancy (mean terms + GP) at the prediction points (link scale)
  vector[P] zeta_new;     // mean of the real process g^-1(g(f) + delta), response scale
  vector[P] y_new;        // a new observation at each prediction point
  {
    real sd_obs = observation_sd(likelihood_id, noise_sd);
    real precision = negbinomial_precision(likelihood_id, inv_sqrt_phi);
    real units = discrepancy_units(likelihood_id, y_scale);
    if (likelihood_id == 1) noise_sd_original[1] = noise_sd[1] * y_scale;
    if (likelihood_id == 3) phi[1] = precision;
    if (use_discrepancy) delta_sd_original[1] = delta_sd[1] * units;
    tuple(vector[N], vector[N], vector[N]) at_points = latent_point_quantities_rng(
      likelihood_id, eta_rest, delta, x_delta, kernel_id, delta_sd, delta_length_scale, sd_obs, precision,
      y_real, y_int, trials, censoring, lower_bound, upper_bound, y_center, y_scale, loo_rule);
    log_lik = at_points.1;
    y_loo_mean = at_points.2;
    y_rep = at_points.3;
    delta_gp = units * delta;

    // functional theta on the grid and at the prediction points, given the points
    tuple(matrix[G, F], matrix[P, Q]) functional = functional_theta_quantities_rng(
      theta_unit, functional_slot, theta_function_logit, x_fun, x_fun_grid, x_fun_new, kernel_id,
      theta_function_sd, theta_function_length_scale, theta_lower, theta_upper, normals_new);
    theta_function_grid = functional.1;
    matrix[P, Q] theta_new_unit = functional.2;
    vector[P] f_link_new = simulator_model_scale(
      likelihood_id,
      // one simulator call for all new points when theta is shared
      simulator_at_rows(X_new, theta_rows_original(F > 0 ? theta_new_unit : to_matrix(theta_unit'),
                                                   theta_lower, theta_upper), 0, 1),
      X_new, y_center, y_scale);
    tuple(vector[P], vector[P], vector[P], vector[P]) at_new = latent_prediction_quantities_rng(
      likelihood_id, f_link_new, h_new * beta, delta, x_delta, x_delta_new, kernel_id, delta_sd, delta_length_scale,
      normals_new, sd_obs, precision, trials_new, units, y_center, y_scale);
    f_new = at_new.1;
    delta_new = at_new.2;
    zeta_new = at_new.3;
    y_new = at_new.4;
  }
}
