// Modular (two-stage) KOH calibration of a vector output (Higdon et al.
// 2008; review section 8.1.1). Each run returns a vector over one grid of
// output indices; the runs' principal components k_c (stancal.output_basis)
// reduce it to C weights, each emulated by a GP over (x, theta) fixed after
// stage 1 (stancal.vector_emulator). Experiment e, at inputs x_e, measures
// the output at its own indices t_ei (interpolated components: ragged):
//   y_ei = mu(t_ei) + s (sum_c k_c(t_ei) w_c(x_e, theta, theta_e)
//                        + truncation_ei + delta(x_e, t_ei) + e_ei),
// with w_c given the runs' weights normal (component_weights), the basis'
// truncation error independent with the variance the components leave in
// the runs, delta a GP over (inputs, output index) and e_ei the measurement
// error (known per value, one sd, or one per experiment). theta is shared;
// theta_e, if any, belongs to experiment e. The weights and delta are
// integrated out: the values' covariance is dense, N x N per gradient.
functions {
#include gp_kernels.stan
#include gp_conditional.stan
#include priors.stan
#include scaling.stan
#include vector_output.stan
}
data {
  int<lower=1> E;                       // number of experiments
  int<lower=1> D;                       // number of simulator inputs
  int<lower=1> Q;                       // number of shared calibration parameters
  int<lower=0> Q_exp;                   // number of per-experiment parameters
  int<lower=1> N;                       // number of measured values
  array[N] int<lower=1, upper=E> experiment;  // each value's experiment
  array[E] vector[D] x;                 // each experiment's inputs, scaled to [0, 1]
  int<lower=1> K_index;                 // number of output index columns
  array[N] vector[K_index] index;       // each value's output index, scaled to [0, 1]
  vector[N] y;                          // (measured - mu(index)) / s
  vector[N] output_mean;                // mu(index): the runs' mean vector at each value's index
  real<lower=0> output_scale;           // s: original = mu + s * standardised
  int<lower=1> C;                       // number of basis components
  matrix[N, C] components;              // k_c at each value's index
  real<lower=0> truncation_variance;    // what the components leave of the runs, standardised
  int<lower=0, upper=2> noise_mode;     // 0 = known per value, 1 = one sd, 2 = one per experiment
  vector<lower=0>[N] known_noise_sd;    // standardised; used when noise_mode = 0
  int<lower=0, upper=1> use_discrepancy;     // 1 = GP over (inputs, output index), 0 = none
  vector[Q] theta_lower;                // bounds of theta, original units (uniform prior)
  vector<lower=theta_lower>[Q] theta_upper;  // see theta_lower
  vector[Q_exp] theta_exp_lower;        // bounds of each per-experiment parameter
  vector<lower=theta_exp_lower>[Q_exp] theta_exp_upper;  // see theta_exp_lower
  int<lower=1> M;                       // number of runs
  array[M] vector[D + Q + Q_exp] xt_runs;  // (inputs, theta, per-experiment theta) of each run, [0, 1]
  matrix[M, C] run_weights;             // each run's component weights
  vector[C] emulator_mean;              // stage 1, per component: the weight GP's mean
  vector<lower=0>[C] emulator_sd;       // its marginal sd
  array[C, D + Q + Q_exp] real<lower=0> emulator_length_scale;  // its length scales, unit-cube units
  vector<lower=0>[C] emulator_nugget;   // its nugget sd
  int<lower=0> P;                       // number of prediction values (experiment, index)
  array[P] int<lower=1, upper=E> experiment_new;  // each prediction row's experiment
  array[P] vector[K_index] index_new;   // its output index, scaled to [0, 1]
  vector[P] output_mean_new;            // mu there
  matrix[P, C] components_new;          // k_c there
  int<lower=0, upper=1> prior_only;     // 1 = ignore y
}
transformed data {
  int n_noise = noise_mode == 0 ? 0 : (noise_mode == 1 ? 1 : E);
  array[C] matrix[M, M] L_runs;
  matrix[M, C] alpha;
  for (c in 1:C) {
    L_runs[c] = cholesky_decompose(emulator_run_cov(xt_runs, 1, emulator_sd[c], emulator_length_scale[c],
                                                    emulator_nugget[c]));
    alpha[:, c] = mdivide_right_tri_low(mdivide_left_tri_low(L_runs[c], run_weights[:, c] - emulator_mean[c])',
                                        L_runs[c])';
  }
  array[N] vector[D + K_index] x_delta;      // the discrepancy's inputs: the experiment's, then the index
  for (i in 1:N) x_delta[i] = append_row(x[experiment[i]], index[i]);
  array[P] vector[D + K_index] x_delta_new;
  for (i in 1:P) x_delta_new[i] = append_row(x[experiment_new[i]], index_new[i]);
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;                  // theta rescaled to [0, 1]
  array[E] vector<lower=0, upper=1>[Q_exp] theta_exp_unit; // per-experiment theta rescaled to [0, 1]
  array[n_noise] real<lower=0> noise_sd;                   // standardised units
  array[use_discrepancy] real<lower=0> delta_sd;           // standardised units
  array[use_discrepancy ? D + K_index : 0] real<lower=0> delta_length_scale;  // fractions of each range
}
transformed parameters {
  vector[Q] theta = theta_from_unit(theta_unit, theta_lower, theta_upper);
  array[E] vector[Q_exp] theta_experiment;
  for (e in 1:E) theta_experiment[e] = theta_from_unit(theta_exp_unit[e], theta_exp_lower, theta_exp_upper);
}
model {
  noise_sd ~ normal(0, 1);
  delta_sd ~ normal(0, 0.5);
  delta_length_scale ~ discrepancy_length_scale();
  if (!prior_only) {
    tuple(matrix[E, C], array[C] matrix[E, E]) w
      = experiment_weights(x, theta_unit, theta_exp_unit, xt_runs, L_runs, alpha, emulator_mean, emulator_sd,
                           emulator_length_scale);
    matrix[N, N] K = add_diag(signal_cov(experiment, components, x_delta, experiment, components, x_delta,
                                         w.2, delta_sd, delta_length_scale),
                              independent_variance(noise_mode, known_noise_sd, noise_sd, experiment)
                              + truncation_variance);
    y ~ multi_normal_cholesky(rows_dot_product(components, w.1[experiment]),
                              cholesky_decompose(add_jitter(K, max(emulator_sd) ^ 2)));
  }
}
generated quantities {
  array[n_noise] real noise_sd_original;
  array[use_discrepancy] real delta_sd_original;
  vector[N] y_rep;        // replicated values at the measured rows, original units
  vector[P] f_new;        // emulated simulator output at the prediction rows, original units
  vector[P] delta_new;    // discrepancy there, original units
  vector[P] zeta_new;     // the real process f + delta there, original units
  for (k in 1:n_noise) noise_sd_original[k] = noise_sd[k] * output_scale;
  if (use_discrepancy) delta_sd_original[1] = delta_sd[1] * output_scale;
  {
    tuple(matrix[E, C], array[C] matrix[E, E]) w
      = experiment_weights(x, theta_unit, theta_exp_unit, xt_runs, L_runs, alpha, emulator_mean, emulator_sd,
                           emulator_length_scale);
    vector[N] mu = rows_dot_product(components, w.1[experiment]);
    vector[P] mu_new = rows_dot_product(components_new, w.1[experiment_new]);
    matrix[N, N] L = cholesky_decompose(add_jitter(
      add_diag(signal_cov(experiment, components, x_delta, experiment, components, x_delta, w.2,
                          delta_sd, delta_length_scale),
               independent_variance(noise_mode, known_noise_sd, noise_sd, experiment) + truncation_variance),
      max(emulator_sd) ^ 2));
    y_rep = output_mean + output_scale * (mu + L * std_normals_rng(N));
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
    vector[2 * P] joint  // (emulator error, delta) at the prediction rows
      = prior_only ? gp_prior_draw(joint_cov, std_normals_rng(2 * P))
                   : gp_conditional_draw(y - mu, L, append_row(emulator_cross, delta_cross), joint_cov,
                                         std_normals_rng(2 * P));
    f_new = output_mean_new + output_scale * (mu_new + joint[1:P]);
    delta_new = output_scale * joint[(P + 1):(2 * P)];
    zeta_new = f_new + delta_new;
  }
}
