// Kennedy-O'Hagan calibration of a vector output with a cheap simulator
// written in Stan (review sections 4.1 and 8.1.1). Experiment e, at inputs
// x_e, measures the output at its own indices t_ei (ragged):
//   y_ei = f(x_e, t_ei; theta, theta_e) + h(e, t_ei)' beta + delta(x_e, z_e, t_ei) + e_ei,
// where simulator(X, theta) takes rows X = (inputs..., output index...),
// theta is shared and theta_e (if any) belongs to experiment e, delta is a
// GP over (inputs, output index, covariates z_e) and e_ei the measurement
// error (known per value, one sd, or one per experiment). No basis is
// needed: the simulator is evaluated at every measured value. The mean
// terms h (H = 0 by default) carry a candidate unmodelled effect.
// Outputs are standardised inside: y = (y_original - y_center) / y_scale.
functions {
#include simulator.stan
#include simulator_output.stan
#include vector_simulator.stan
#include vector_noise.stan
#include gp_kernels.stan
#include gp_conditional.stan
#include loo.stan
#include priors.stan
#include scaling.stan
}
data {
  int<lower=1> E;                       // number of experiments
  int<lower=0> D;                       // number of simulator inputs (0: experiments differ by theta_e alone)
  int<lower=1> K_index;                 // number of output index columns
  int<lower=0> D_cov;                   // number of covariates (discrepancy only)
  int<lower=1> Q;                       // number of shared calibration parameters
  int<lower=0> Q_exp;                   // number of per-experiment parameters
  int<lower=1> N;                       // number of measured values
  array[N] int<lower=1, upper=E> experiment;  // each value's experiment
  matrix[N, D + K_index] X;             // simulator rows (inputs, output index), original units
  array[N] vector[D + K_index + D_cov] x_delta;  // discrepancy inputs (inputs, index, covariates), [0, 1]
  vector[N] y;                          // measured values, standardised
  real y_center;                        // original = y_center + y_scale * standardised
  real<lower=0> y_scale;                // see y_center
  int<lower=0, upper=2> noise_mode;     // 0 = known per value, 1 = one sd, 2 = one per experiment
  vector<lower=0>[N] known_noise_sd;    // standardised; used when noise_mode = 0
  int<lower=0, upper=1> use_discrepancy;     // 1 = GP discrepancy, 0 = none
  int<lower=1, upper=2> kernel_id;      // discrepancy kernel: 1 = squared exponential, 2 = Matern 5/2
  int<lower=0> H;                       // number of discrepancy mean terms (0 = zero mean)
  matrix[N, H] h;                       // mean terms at the measured values, scaled to unit RMS
  vector<lower=0>[H] beta_prior_sd;     // prior sd of each coefficient, standardised units
  vector[Q] theta_lower;                // bounds of theta, original units (uniform prior)
  vector<lower=theta_lower>[Q] theta_upper;  // see theta_lower
  vector[Q_exp] theta_exp_lower;        // bounds of each per-experiment parameter
  vector<lower=theta_exp_lower>[Q_exp] theta_exp_upper;  // see theta_exp_lower
  int<lower=0> P;                       // number of prediction values (experiment, index)
  array[P] int<lower=1, upper=E> experiment_new;  // each prediction row's experiment
  matrix[P, D + K_index] X_new;         // its simulator row, original units
  array[P] vector[D + K_index + D_cov] x_delta_new;  // its discrepancy inputs, [0, 1]
  matrix[P, H] h_new;                   // its mean terms, scaled like h
  int<lower=0, upper=1> prior_only;     // 1 = ignore y
}
transformed data {
  int n_noise = noise_mode == 0 ? 0 : (noise_mode == 1 ? 1 : E);
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;                  // theta rescaled to [0, 1]
  array[E] vector<lower=0, upper=1>[Q_exp] theta_exp_unit; // per-experiment theta rescaled to [0, 1]
  array[n_noise] real<lower=0> noise_sd;                   // standardised units
  array[use_discrepancy] real<lower=0> delta_sd;           // standardised units
  array[use_discrepancy ? D + K_index : 0] real<lower=0> delta_input_length_scale;  // fractions of each range
  array[use_discrepancy ? D_cov : 0] real<lower=0> delta_relevance;  // covariates: inverse length scale
  vector[H] beta;                                          // mean-term coefficients, standardised units
}
transformed parameters {
  vector[Q] theta = theta_from_unit(theta_unit, theta_lower, theta_upper);
  array[E] vector[Q_exp] theta_experiment;
  for (e in 1:E) theta_experiment[e] = theta_from_unit(theta_exp_unit[e], theta_exp_lower, theta_exp_upper);
  // the discrepancy's length scales over all its inputs: a covariate's is 1 / relevance
  array[use_discrepancy ? D + K_index + D_cov : 0] real delta_length_scale
    = discrepancy_length_scales(delta_input_length_scale, delta_relevance);
}
model {
  noise_sd ~ observation_noise_sd();                 // half-normal(0, 1)
  delta_sd ~ discrepancy_sd();                       // half-normal(0, 0.5)
  delta_input_length_scale ~ discrepancy_length_scale();  // inverse gamma(3, 1)
  delta_relevance ~ covariate_relevance();           // half-normal(0, 2)
  beta ~ normal(0, beta_prior_sd);
  if (!prior_only) {
    vector[N] resid = y - experiment_simulator(X, experiment, theta, theta_experiment, y_center, y_scale)
                      - h * beta;
    vector[N] variance = independent_variance(noise_mode, known_noise_sd, noise_sd, experiment);
    if (use_discrepancy) {
      matrix[N, N] K = add_diag(ard_cov(x_delta, kernel_id, delta_sd[1], delta_length_scale), variance);
      resid ~ multi_normal_cholesky(rep_vector(0, N), cholesky_decompose(add_jitter(K, square(delta_sd[1]))));
    } else {
      resid ~ normal(0, sqrt(variance));
    }
  }
}
generated quantities {
  array[n_noise] real noise_sd_original;
  array[use_discrepancy] real delta_sd_original;
  vector[N] log_lik;        // log p(y_i | y_-i, parameters), original units
  vector[N] y_rep;          // replicated values, original units
  vector[N] y_loo_mean;     // E(y_i | y_-i, parameters), original units
  vector[N] delta_gp;       // GP part of the discrepancy at the measured values, original units
  vector[N] delta_gp_mean;  // its mean given the data and parameters, original units
  vector[P] f_new;          // simulator output at the prediction rows, original units
  vector[P] delta_new;      // discrepancy there (mean terms and GP), original units
  vector[P] zeta_new;       // the real process f + delta there, original units
  for (k in 1:n_noise) noise_sd_original[k] = noise_sd[k] * y_scale;
  if (use_discrepancy) delta_sd_original[1] = delta_sd[1] * y_scale;
  {
    vector[N] f = experiment_simulator(X, experiment, theta, theta_experiment, y_center, y_scale);
    vector[N] mean_terms = h * beta;
    vector[N] resid = y - f - mean_terms;
    vector[N] variance = independent_variance(noise_mode, known_noise_sd, noise_sd, experiment);
    vector[N] resid_loo_mean = rep_vector(0, N);
    vector[N] delta_obs = rep_vector(0, N);
    vector[N] delta_obs_mean = rep_vector(0, N);
    vector[P] delta_new_std = rep_vector(0, P);
    if (use_discrepancy) {
      matrix[N, N] K_delta = ard_cov(x_delta, kernel_id, delta_sd[1], delta_length_scale);
      matrix[N, N] L = cholesky_decompose(add_jitter(add_diag(K_delta, variance), square(delta_sd[1])));
      tuple(vector[N], vector[N]) loo = mvn_loo(resid, L);
      log_lik = loo.1;
      resid_loo_mean = loo.2;
      matrix[P, P] K_new = ard_cov(x_delta_new, kernel_id, delta_sd[1], delta_length_scale);
      if (prior_only) {
        delta_obs = gp_prior_draw(K_delta, std_normals_rng(N));
        if (P > 0) delta_new_std = gp_prior_draw(K_new, std_normals_rng(P));
      } else {
        matrix[P, N] K_cross = ard_cross_cov(x_delta_new, x_delta, kernel_id, delta_sd[1], delta_length_scale);
        delta_obs = gp_conditional_draw(resid, L, K_delta, K_delta, std_normals_rng(N));
        delta_obs_mean = gp_conditional_mean(resid, L, K_delta);
        if (P > 0) delta_new_std = gp_conditional_draw(resid, L, K_cross, K_new, std_normals_rng(P));
      }
    } else {
      for (i in 1:N) log_lik[i] = normal_lpdf(resid[i] | 0, sqrt(variance[i]));
    }
    log_lik -= log(y_scale);
    y_rep = y_center + y_scale * to_vector(normal_rng(f + mean_terms + delta_obs, sqrt(variance)));
    y_loo_mean = y_center + y_scale * (y - resid + resid_loo_mean);
    delta_gp = y_scale * delta_obs;
    delta_gp_mean = y_scale * delta_obs_mean;
    vector[P] f_new_std = experiment_simulator(X_new, experiment_new, theta, theta_experiment, y_center, y_scale);
    f_new = y_center + y_scale * f_new_std;
    delta_new = y_scale * (h_new * beta + delta_new_std);
    zeta_new = f_new + delta_new;
  }
}
