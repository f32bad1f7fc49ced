// KOH calibration of a vector output from simulator runs (Higdon et al.
// 2008; review section 8.1.1). Each run returns a vector over one grid of
// output indices; the runs' principal components k_c (stancal.output_basis)
// reduce it to C weights, each emulated by a GP over (x, theta). Modular
// (joint = 0): the GPs' hyperparameters are fixed after stage 1
// (stancal.vector_emulator). Joint (joint = 1, method koh_emulator): they
// are sampled with theta, the runs' weights entering the likelihood. Experiment e, at inputs x_e, measures
// the output at its own indices t_ei (interpolated components: ragged):
//   y_ei = mu(t_ei) + s (sum_c k_c(t_ei) w_c(x_e, theta, theta_e)
//                        + truncation_ei + delta(x_e, t_ei) + e_ei),
// with w_c given the runs' weights normal (component_weights: its mean
// given every run, its covariance given a subset of them, at most a few
// hundred: a GP given fewer runs is never more certain; plus the GP's
// nugget, one per distinct (x_e, theta_e)), the basis'
// truncation error independent with the variance the components leave in
// the runs (plus the interpolation's, off the runs' grid), delta =
// h(e, t_ei)' beta + a GP over (inputs, output index, covariates z_e)
// and e_ei the measurement
// error (known per value, one sd, or one per experiment). theta is shared;
// theta_e, if any, belongs to experiment e. The weights and delta are
// integrated out: the values' covariance is dense, N x N per gradient.
// The mean terms h (H = 0 by default) carry a candidate unmodelled effect.
// Runs of cheaper simulators (n_levels > 1, modular only): each weight's emulator is
// autoregressive over the levels (Kennedy & O'Hagan 2000; vector_fidelity.stan),
// the basis the calibrated simulator's, the experiments at the top level;
// with n_levels = 1 the program is the single-fidelity one above.
functions {
#include gp_kernels.stan
#include gp_conditional.stan
#include priors.stan
#include scaling.stan
#include vector_output.stan
#include fidelity.stan
#include vector_fidelity.stan
#include vector_noise.stan
#include loo.stan
}
data {
  int<lower=1> E;                       // number of experiments
  int<lower=0> D;                       // number of simulator inputs (0: experiments differ by theta_e alone)
  int<lower=1> Q;                       // number of shared calibration parameters
  int<lower=0> Q_exp;                   // number of per-experiment parameters
  int<lower=1> N;                       // number of measured values
  array[N] int<lower=1, upper=E> experiment;  // each value's experiment
  array[E] vector[D] x;                 // each experiment's inputs, scaled to [0, 1]
  matrix<lower=0, upper=1>[E, E] same_point;  // 1 where two experiments' emulator inputs (x_e, theta_e) are
                                        // identical (their weights share the nugget), else 0
  int<lower=0> D_cov;                   // number of covariates (discrepancy only)
  array[E] vector[D_cov] z;             // each experiment's covariates, scaled to [0, 1]
  int<lower=1> K_index;                 // number of output index columns
  array[N] vector[K_index] index;       // each value's output index, scaled to [0, 1]
  vector[N] y;                          // (measured - mu(index)) / s
  vector[N] output_mean;                // mu(index): the runs' mean vector at each value's index
  real<lower=0> output_scale;           // s: original = mu + s * standardised
  int<lower=1> C;                       // number of basis components
  matrix[N, C] components;              // k_c at each value's index
  vector<lower=0>[N] truncation_variance;  // per value: what the components leave of the runs, plus,
                                        // for a value off the runs' grid, the error of interpolating them
                                        // there; standardised
  int<lower=0, upper=2> noise_mode;     // 0 = known per value, 1 = one sd, 2 = one per experiment
  vector<lower=0>[N] known_noise_sd;    // standardised; used when noise_mode = 0
  int<lower=0, upper=1> use_discrepancy;     // 1 = GP over (inputs, output index, covariates), 0 = none
  int<lower=0> H;                       // number of discrepancy mean terms (0 = zero mean)
  matrix[N, H] h;                       // mean terms at the measured values, scaled to unit RMS
  vector<lower=0>[H] beta_prior_sd;     // prior sd of each coefficient, standardised units
  vector[Q] theta_lower;                // bounds of theta, original units (uniform prior)
  vector<lower=theta_lower>[Q] theta_upper;  // see theta_lower
  vector[Q_exp] theta_exp_lower;        // bounds of each per-experiment parameter
  vector<lower=theta_exp_lower>[Q_exp] theta_exp_upper;  // see theta_exp_lower
  int<lower=1> M;                       // number of runs
  array[M] vector[D + Q + Q_exp] xt_runs;  // (inputs, theta, per-experiment theta) of each run, [0, 1]
  int<lower=0, upper=1> joint;          // 1 = sample the weight GPs' hyperparameters (koh_emulator)
  matrix[M, C] run_weights;             // each run's component weights (the joint likelihood)
  matrix[M, C] emulator_alpha;          // stage 1, per component: K^-1 (run weights - mean), all runs
  int<lower=1, upper=M> M_variance;     // number of runs the weights' covariance conditions on
  array[M_variance] int<lower=1, upper=M> variance_runs;  // which runs
  vector[C] emulator_mean;              // stage 1 (modular), per component: the weight GP's mean
  vector<lower=0>[C] emulator_sd;       // its marginal sd
  array[C, D + Q + Q_exp] real<lower=0> emulator_length_scale;  // its length scales, unit-cube units
  vector<lower=0>[C] emulator_nugget;   // its nugget sd
  // runs of several fidelities (modular only): emulator_* above are then the top level's own GP
  int<lower=1> n_levels;                // fidelity levels of the runs: 1 = the calibrated simulator only
  array[M] int<lower=1, upper=n_levels> run_level;  // each run's level: 1 the cheapest, n_levels the calibrated one
  array[C] vector[n_levels - 1] level_rho;     // stage 1, per component: each level's scale on the level below
  array[C, n_levels - 1] real level_mean;      // stage 1, per component: the cheaper levels' GP means
  array[C, n_levels - 1] real<lower=0> level_sd;  // their marginal sds
  array[C, n_levels - 1, D + Q + Q_exp] real<lower=0> level_length_scale;  // their length scales, unit cube
  array[C, n_levels - 1] real<lower=0> level_nugget;  // their nugget sds
  int<lower=0> P;                       // number of prediction values (experiment, index)
  array[P] int<lower=1, upper=E> experiment_new;  // each prediction row's experiment
  array[P] vector[K_index] index_new;   // its output index, scaled to [0, 1]
  vector[P] output_mean_new;            // mu there
  matrix[P, C] components_new;          // k_c there
  matrix[P, H] h_new;                   // mean terms there, scaled like h
  int<lower=0, upper=1> prior_only;     // 1 = ignore y
}
transformed data {
  int n_noise = noise_mode == 0 ? 0 : (noise_mode == 1 ? 1 : E);
  array[M_variance] vector[D + Q + Q_exp] xt_variance = xt_runs[variance_runs];
  if (joint && n_levels > 1) {
    reject("joint = 1 (method koh_emulator) takes runs of one fidelity; for runs of several, set joint = 0 ",
           "(method modular), or leave the cheaper runs out");
  }
  // per component, every level's GP (the cheaper ones', then the top's own), each run's weights on them
  // (fidelity_weights), the top level's and its prior mean
  array[C, n_levels] real all_sd;
  array[C, n_levels, D + Q + Q_exp] real all_length_scale;
  array[C] matrix[M, n_levels] w_runs;
  array[C] row_vector[n_levels] w_top;
  vector[C] top_mean;
  for (c in 1:C) {
    all_sd[c] = append_array(level_sd[c], {emulator_sd[c]});
    all_length_scale[c] = append_array(level_length_scale[c], {emulator_length_scale[c]});
    matrix[n_levels, n_levels] w = fidelity_weights(level_rho[c]);
    w_runs[c] = w[run_level];
    w_top[c] = w[n_levels];
    top_mean[c] = w_top[c] * to_vector(append_array(level_mean[c], {emulator_mean[c]}));
  }
  // the likelihood's jitter scale (modular): the widest component's prior variance of the top level, every
  // level's share in it (fidelity_variance; emulator_sd^2 with one level)
  real top_variance = 0;
  for (c in 1:C) top_variance = fmax(top_variance, fidelity_variance(w_top[c], all_sd[c]));
  array[C] matrix[M_variance, M_variance] L_variance;  // Cholesky factors of the variance runs' covariance
  for (c in 1:(joint ? 0 : C)) {
    L_variance[c] = cholesky_decompose(n_levels == 1
      ? emulator_run_cov(xt_variance, 1, emulator_sd[c], emulator_length_scale[c], emulator_nugget[c])
      : fidelity_run_cov(xt_variance, w_runs[c][variance_runs], w_top[c], 1, all_sd[c], all_length_scale[c],
                         to_vector(append_array(level_nugget[c], {emulator_nugget[c]}))[run_level[variance_runs]]));
  }
  // the discrepancy's inputs: the experiment's inputs, the index, the experiment's covariates
  array[N] vector[D + K_index + D_cov] x_delta;
  for (i in 1:N) x_delta[i] = append_row(x[experiment[i]], append_row(index[i], z[experiment[i]]));
  array[P] vector[D + K_index + D_cov] x_delta_new;
  for (i in 1:P) x_delta_new[i] = append_row(x[experiment_new[i]], append_row(index_new[i], z[experiment_new[i]]));
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;                  // theta rescaled to [0, 1]
  array[E] vector<lower=0, upper=1>[Q_exp] theta_exp_unit; // per-experiment theta rescaled to [0, 1]
  array[n_noise] real<lower=0> noise_sd;                   // standardised units
  array[use_discrepancy] real<lower=0> delta_sd;           // standardised units
  array[use_discrepancy ? D + K_index : 0] real<lower=0> delta_input_length_scale;  // fractions of each range
  array[use_discrepancy ? D_cov : 0] real<lower=0> delta_relevance;  // covariates: inverse length scale
  vector[H] beta;                                          // mean-term coefficients, standardised units
  // joint only: the weight GPs' hyperparameters, per component (inputs, theta, per-experiment theta)
  vector[joint ? C : 0] weight_gp_mean_free;
  vector<lower=0>[joint ? C : 0] weight_gp_sd_free;
  array[joint ? C : 0, D + Q + Q_exp] real<lower=0> weight_gp_length_scale_free;
  vector<lower=0>[joint ? C : 0] weight_gp_nugget_free;
}
transformed parameters {
  // the discrepancy's length scales over all its inputs: a covariate's is 1 / relevance
  array[use_discrepancy ? D + K_index + D_cov : 0] real delta_length_scale
    = discrepancy_length_scales(delta_input_length_scale, delta_relevance);
  vector[C] weight_gp_mean = joint ? weight_gp_mean_free : emulator_mean;
  vector[C] weight_gp_sd = joint ? weight_gp_sd_free : emulator_sd;
  array[C, D + Q + Q_exp] real weight_gp_length_scale = joint ? weight_gp_length_scale_free : emulator_length_scale;
  vector[C] weight_gp_nugget = joint ? weight_gp_nugget_free : emulator_nugget;
  vector[Q] theta = theta_from_unit(theta_unit, theta_lower, theta_upper);
  array[E] vector[Q_exp] theta_experiment;
  for (e in 1:E) theta_experiment[e] = theta_from_unit(theta_exp_unit[e], theta_exp_lower, theta_exp_upper);
}
model {
  noise_sd ~ observation_noise_sd();                 // half-normal(0, 1)
  delta_sd ~ discrepancy_sd();                       // half-normal(0, 0.5)
  delta_input_length_scale ~ discrepancy_length_scale();  // inverse gamma(3, 1)
  delta_relevance ~ covariate_relevance();           // half-normal(0, 2)
  beta ~ normal(0, beta_prior_sd);
  // emulator.stan's priors; the weights have unit variance
  weight_gp_mean_free ~ emulator_mean();             // normal(0, 1)
  weight_gp_sd_free ~ emulator_sd();                 // half-normal(0, 1)
  for (c in 1:(joint ? C : 0)) weight_gp_length_scale_free[c] ~ emulator_length_scale();  // inverse gamma(2, 1)
  weight_gp_nugget_free ~ emulator_nugget();         // half-normal(0, 0.05)
  if (!prior_only) {
    tuple(matrix[E, C], array[C] matrix[E, E]) w;
    if (joint) {
      tuple(array[C] matrix[M, M], matrix[M, C]) runs
        = weight_gp_factors(xt_runs, run_weights, weight_gp_mean, weight_gp_sd, weight_gp_length_scale,
                            weight_gp_nugget);
      for (c in 1:C) run_weights[:, c] ~ multi_normal_cholesky(rep_vector(weight_gp_mean[c], M), runs.1[c]);
      w = experiment_weights(x, theta_unit, theta_exp_unit, xt_runs, runs.2, xt_runs, runs.1, weight_gp_mean,
                             weight_gp_sd, weight_gp_length_scale, weight_gp_nugget, same_point);
    } else if (n_levels == 1) {
      w = experiment_weights(x, theta_unit, theta_exp_unit, xt_runs, emulator_alpha, xt_variance, L_variance,
                             weight_gp_mean, weight_gp_sd, weight_gp_length_scale, weight_gp_nugget, same_point);
    } else {
      w = fidelity_experiment_weights(emulator_points(x, theta_unit, theta_exp_unit), xt_runs, w_runs,
                                      emulator_alpha, variance_runs, L_variance, w_top, top_mean, all_sd,
                                      all_length_scale, emulator_nugget, same_point);
    }
    matrix[N, N] K = add_diag(signal_cov(experiment, components, x_delta, experiment, components, x_delta,
                                         w.2, delta_sd, delta_length_scale),
                              independent_variance(noise_mode, known_noise_sd, noise_sd, experiment)
                              + truncation_variance);
    y ~ multi_normal_cholesky(rows_dot_product(components, w.1[experiment]) + h * beta,
                              cholesky_decompose(add_jitter(K, joint ? max(weight_gp_sd) ^ 2 : top_variance)));
  }
}
generated quantities {
  array[n_noise] real noise_sd_original;
  array[use_discrepancy] real delta_sd_original;
  vector[N] y_rep;        // replicated values at the measured rows, original units
  vector[N] log_lik;      // log p(y_i | y_-i, parameters), original units
  vector[N] y_loo_mean;   // E(y_i | y_-i, parameters), original units
  vector[N] delta_gp;     // GP part of the discrepancy at the measured values, original units
  vector[N] delta_gp_mean;  // its mean given the data and parameters, original units
  vector[P] f_new;        // emulated simulator output at the prediction rows, original units
  vector[P] delta_new;    // discrepancy there, original units
  vector[P] zeta_new;     // the real process f + delta there, original units
  for (k in 1:n_noise) noise_sd_original[k] = noise_sd[k] * output_scale;
  if (use_discrepancy) delta_sd_original[1] = delta_sd[1] * output_scale;
  {
    tuple(matrix[E, C], array[C] matrix[E, E]) w;
    if (joint) {
      tuple(array[C] matrix[M, M], matrix[M, C]) runs
        = weight_gp_factors(xt_runs, run_weights, weight_gp_mean, weight_gp_sd, weight_gp_length_scale,
                            weight_gp_nugget);
      w = experiment_weights(x, theta_unit, theta_exp_unit, xt_runs, runs.2, xt_runs, runs.1, weight_gp_mean,
                             weight_gp_sd, weight_gp_length_scale, weight_gp_nugget, same_point);
    } else if (n_levels == 1) {
      w = experiment_weights(x, theta_unit, theta_exp_unit, xt_runs, emulator_alpha, xt_variance, L_variance,
                             weight_gp_mean, weight_gp_sd, weight_gp_length_scale, weight_gp_nugget, same_point);
    } else {
      w = fidelity_experiment_weights(emulator_points(x, theta_unit, theta_exp_unit), xt_runs, w_runs,
                                      emulator_alpha, variance_runs, L_variance, w_top, top_mean, all_sd,
                                      all_length_scale, emulator_nugget, same_point);
    }
    vector[N] mu = rows_dot_product(components, w.1[experiment]) + h * beta;
    vector[P] mu_new = rows_dot_product(components_new, w.1[experiment_new]);
    matrix[N, N] L = cholesky_decompose(add_jitter(
      add_diag(signal_cov(experiment, components, x_delta, experiment, components, x_delta, w.2,
                          delta_sd, delta_length_scale),
               independent_variance(noise_mode, known_noise_sd, noise_sd, experiment) + truncation_variance),
      joint ? max(weight_gp_sd) ^ 2 : top_variance));
    y_rep = output_mean + output_scale * (mu + L * std_normals_rng(N));
    tuple(vector[N], vector[N]) loo = mvn_loo(y - mu, L);
    log_lik = loo.1 - log(output_scale);
    y_loo_mean = output_mean + output_scale * (mu + loo.2);
    delta_gp = rep_vector(0, N);
    delta_gp_mean = rep_vector(0, N);
    if (use_discrepancy) {
      matrix[N, N] K_delta = gp_exp_quad_cov(x_delta, delta_sd[1], delta_length_scale);
      delta_gp = output_scale * (prior_only ? gp_prior_draw(K_delta, std_normals_rng(N))
                                            : gp_conditional_draw(y - mu, L, K_delta, K_delta, std_normals_rng(N)));
      if (!prior_only) delta_gp_mean = output_scale * gp_conditional_mean(y - mu, L, K_delta);
    }
    // the emulator's error and delta at the prediction rows, jointly given the data (or the prior)
    array[0] real none = rep_array(0.0, 0);  // no discrepancy: the emulator part alone
    matrix[P, P] zero = rep_matrix(0, P, P);
    matrix[P, P] emulator_new = signal_cov(experiment_new, components_new, x_delta_new, experiment_new,
                                           components_new, x_delta_new, w.2, none, none);
    matrix[P, N] emulator_cross = signal_cov(experiment_new, components_new, x_delta_new, experiment,
                                             components, x_delta, w.2, none, none);
    matrix[P, P] delta_cov_new = use_discrepancy
      ? gp_exp_quad_cov(x_delta_new, delta_sd[1], delta_length_scale) : zero;
    matrix[P, N] delta_cross = use_discrepancy
      ? gp_exp_quad_cov(x_delta_new, x_delta, delta_sd[1], delta_length_scale) : rep_matrix(0, P, N);
    matrix[2 * P, 2 * P] joint_cov = append_row(append_col(emulator_new, zero), append_col(zero, delta_cov_new));
    vector[2 * P] at_new  // (emulator error, delta) at the prediction rows
      = prior_only ? gp_prior_draw(joint_cov, std_normals_rng(2 * P))
                   : gp_conditional_draw(y - mu, L, append_row(emulator_cross, delta_cross), joint_cov,
                                         std_normals_rng(2 * P));
    f_new = output_mean_new + output_scale * (mu_new + at_new[1:P]);
    delta_new = output_scale * (h_new * beta + at_new[(P + 1):(2 * P)]);
    zeta_new = f_new + delta_new;
  }
}
