// Full Kennedy-O'Hagan calibration with an expensive simulator
// (review section 4.2): the simulator runs and the physical data enter one
// joint GP likelihood, and theta, the emulator and the discrepancy
// hyperparameters are sampled together.
//   y_sim_j = f(x_sim_j, theta_sim_j) + nugget_j
//   y_i     = rho * f(x_i, theta) + delta(x_i, z_i) + eps_i (functions/noise.stan),
//             plus b_s(x_i) for a reading by a biased source s (functions/source_bias.stan)
//   f ~ GP(emulator_mean, ARD kernel over (x, theta)),
//   delta = h(x_i, z_i)' beta + GP(0, ARD kernel) (H = 0 mean terms by default)
// With runs of cheaper simulators too (L > 1 levels, cheapest first), f is the top
// level of the autoregressive emulator f_1 = g_1, f_k = rho_k f_(k-1) + g_k
// (Kennedy & O'Hagan 2000; functions/fidelity.stan): every level's GP g_k and
// scale rho_k are sampled with theta, all runs of all levels and the readings in
// one joint Gaussian likelihood (Goh et al. 2013). One level: the program above.
// Inputs and theta are scaled to [0, 1]; outputs are standardised.
functions {
#include gp_kernels.stan
#include gp_conditional.stan
#include noise.stan
#include fidelity.stan
#include same_point.stan
#include koh_joint.stan
#include loo.stan
#include priors.stan
#include scaling.stan
#include given_normals.stan
#include source_bias.stan
}
data {
  int<lower=1> N;                       // number of physical observations
  int<lower=1> M;                       // number of simulator runs
  int<lower=1> D;                       // number of simulator inputs
  int<lower=1> D_delta;                 // number of discrepancy inputs: simulator inputs, then covariates
  int<lower=1> Q;                       // number of calibration parameters
  array[N] vector[D] x;                 // simulator inputs of the physical points, scaled to [0, 1]
  array[N] vector[D_delta] x_delta;     // discrepancy inputs of the physical points, scaled to [0, 1]
  vector[N] y;                          // physical output, standardised
  int<lower=0> H;                       // number of discrepancy mean terms (0 = zero mean)
  matrix[N, H] h;                       // mean terms at the physical points, scaled to unit RMS
  vector<lower=0>[H] beta_prior_sd;     // prior sd of each coefficient, standardised units
  array[M] vector[D] x_sim;             // simulator inputs of the runs, scaled to [0, 1]
  array[M] vector[Q] theta_sim;         // theta of the runs, scaled to [0, 1] within its bounds
  vector[M] y_sim;                      // simulator output of the runs, standardised like y
  int<lower=1> L;                       // fidelity levels of the runs: 1 = the calibrated simulator only
  array[M] int<lower=1, upper=L> run_level;  // each run's level: 1 the cheapest, L the calibrated simulator
  real y_center;                        // original-scale y = y_center + y_scale * y
  real<lower=0> y_scale;                // see y_center
  vector[Q] theta_lower;                // lower bounds of theta, original units (uniform prior)
  vector<lower=theta_lower>[Q] theta_upper;  // upper bounds of theta, original units
  int<lower=0, upper=1> use_discrepancy;     // 1 = GP discrepancy, 0 = none
  int<lower=1, upper=2> kernel_id;      // kernel of both GPs: 1 = squared exponential, 2 = Matern 5/2
  int<lower=0, upper=1> estimate_rho;   // 1 = estimate the KOH scale rho, 0 = rho fixed at 1
  int<lower=1, upper=4> noise_id;       // 1 = iid, 2 = per_source, 3 = student_t, 4 = heteroscedastic (functions/noise.stan)
  int<lower=1> S;                       // number of estimated noise sds: the sources with per_source, else 1
  array[N] int<lower=1, upper=S> source;  // each row's noise sd: its source (all 1 unless per_source)
  vector<lower=0>[N] known_sd;          // each row's known measurement sd, standardised (0 = none)
  int<lower=0> N_loc;                   // heteroscedastic: distinct locations of the noise inputs (0 otherwise)
  int<lower=0> D_noise;                 // heteroscedastic: number of noise inputs (simulator inputs)
  array[N_loc] vector[D_noise] x_noise; // heteroscedastic: the distinct locations, scaled to [0, 1]
  array[N_loc > 0 ? N : 0] int<lower=1, upper=N_loc> noise_loc;  // heteroscedastic: each row's location
  vector[2] noise_length_scale_prior;   // heteroscedastic: lognormal location and scale of its length scales
  int<lower=0> n_biased;                // biased measurement sources (functions/source_bias.stan); 0 = none
  array[N] int<lower=0, upper=n_biased> bias_of;  // each row's biased source, 1..n_biased; 0 = a reference source
  int<lower=0, upper=1> prior_only;     // 1 = ignore y (the runs still train the emulator)
  int<lower=0> P;                       // number of prediction points
  array[P] vector[D] x_new;             // simulator inputs of the prediction points, scaled to [0, 1]
  array[P] vector[D_delta] x_delta_new; // discrepancy inputs of the prediction points, scaled to [0, 1]
  matrix[P, H] h_new;                   // mean terms at the prediction points, scaled like h
#include prediction_normals_data.stan
  matrix[P_normals, n_biased] bias_normals_new;  // as normals_new, for the bias curves at the prediction points
}
transformed data {
  array[M] vector[D + Q] xt_sim;
  for (j in 1:M) xt_sim[j] = append_row(x_sim[j], theta_sim[j]);
  vector[M + N] y_joint = append_row(y_sim, y);
  check_given_normals(P_normals, P);
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;                // theta rescaled to [0, 1]
  array[S] real<lower=0> noise_sd;                       // standardised units, one per source (S = 1 unless per_source);
                                                         // heteroscedastic: the sd's geometric mean over the settings
  array[noise_id == 3] real<lower=0> nu;                 // Student-t degrees of freedom
  // Student-t scale-mixture weight of each row (the emulator's GP is integrated out)
  vector<lower=0>[noise_id == 3 ? N : 0] noise_weight;
  array[N_loc > 0] real<lower=0> noise_gp_sd;            // heteroscedastic: the log noise sd GP's marginal sd
  array[N_loc > 0 ? D_noise : 0] real<lower=0> noise_length_scale;  // its length scales: fraction of input range
  vector[N_loc] noise_z;                                 // its non-centred standard normals at the locations
  array[use_discrepancy] real<lower=0> delta_sd;         // standardised units
  array[use_discrepancy ? D : 0] real<lower=0> delta_input_length_scale;  // simulator inputs: fraction of input range
  array[use_discrepancy ? D_delta - D : 0] real<lower=0> delta_relevance;  // covariates: inverse length scale
  array[estimate_rho] real<lower=0> rho_free;
  vector[H] beta;                                        // mean-term coefficients, standardised units
  real emulator_mean;
  real<lower=0> emulator_sd;
  array[D + Q] real<lower=0> emulator_length_scale;     // inputs first, then theta
  real<lower=0> emulator_nugget;
  array[n_biased] real<lower=0> bias_sd;                 // each biased source's bias GP marginal sd, standardised units
  array[n_biased, D] real<lower=0> bias_length_scale;    // its length scales: fraction of each input's range
  // the cheaper levels (none with one fidelity), cheapest first; the emulator_* above are the top level's g_L
  vector[L - 1] level_rho;                               // each level's scale on the level below, levels 2..L
  vector[L - 1] low_emulator_mean;                       // the cheaper levels' GPs g_1..g_(L-1): constant means
  vector<lower=0>[L - 1] low_emulator_sd;                // their marginal sds, standardised units
  array[L - 1, D + Q] real<lower=0> low_emulator_length_scale;  // their length scales: inputs first, then theta
  vector<lower=0>[L - 1] low_emulator_nugget;            // their nugget sds, standardised units
}
transformed parameters {
  // heteroscedastic: the log noise sd's GP at the distinct settings, before centring (functions/noise.stan)
  vector[N_loc] noise_log_scale = noise_log_scale_at(x_noise, noise_gp_sd, noise_length_scale, noise_z);
  // the discrepancy's length scales over all its inputs: a covariate's is 1 / relevance
  array[use_discrepancy ? D_delta : 0] real delta_length_scale
    = discrepancy_length_scales(delta_input_length_scale, delta_relevance);
  vector[Q] theta = theta_from_unit(theta_unit, theta_lower, theta_upper);
  real rho = estimate_rho ? rho_free[1] : 1.0;
}
model {
  noise_sd ~ observation_noise_sd();                 // half-normal(0, 1)
  nu ~ noise_dof();                                  // gamma(2, 0.1)
  noise_weight ~ noise_weight(nu);                   // gamma(nu / 2, nu / 2)
  noise_gp_sd ~ noise_gp_sd();                       // half-normal(0, 1)
  noise_length_scale ~ noise_length_scale(noise_length_scale_prior);  // lognormal
  noise_z ~ std_normal();
  delta_sd ~ discrepancy_sd();                       // half-normal(0, 0.5)
  delta_input_length_scale ~ discrepancy_length_scale();  // inverse gamma(3, 1)
  delta_relevance ~ covariate_relevance();           // half-normal(0, 2)
  rho_free ~ koh_scale();                            // normal(1, 0.25), rho > 0
  beta ~ normal(0, beta_prior_sd);
  emulator_mean ~ emulator_mean();                   // normal(0, 1)
  emulator_sd ~ emulator_sd();                       // half-normal(0, 1)
  emulator_length_scale ~ emulator_length_scale();   // inverse gamma(2, 1)
  emulator_nugget ~ emulator_nugget();               // half-normal(0, 0.05)
  level_rho ~ fidelity_scale();                      // normal(1, 0.5)
  low_emulator_mean ~ emulator_mean();               // the cheaper levels' GPs: the emulator's priors
  low_emulator_sd ~ emulator_sd();
  to_array_1d(low_emulator_length_scale) ~ emulator_length_scale();
  low_emulator_nugget ~ emulator_nugget();
  bias_sd ~ discrepancy_sd();                        // half-normal(0, 0.5), as delta's
  to_array_1d(bias_length_scale) ~ discrepancy_length_scale();  // inverse gamma(3, 1), as delta's
  // every level's GP, cheapest first, and each run's weights on them (functions/fidelity.stan)
  matrix[L, L] w_level = fidelity_weights(level_rho);
  matrix[M, L] w_sim = w_level[run_level];
  row_vector[L] w_top = w_level[L];
  array[L] real level_sd = append_array(to_array_1d(low_emulator_sd), {emulator_sd});
  array[L, D + Q] real level_length_scale = append_array(low_emulator_length_scale, {emulator_length_scale});
  vector[M] run_nugget_sd = append_row(low_emulator_nugget, emulator_nugget)[run_level];
  vector[M] run_mean = w_sim * append_row(low_emulator_mean, emulator_mean);
  if (prior_only) {
    matrix[M, M] K_sim = fidelity_run_cov(xt_sim, w_sim, w_top, kernel_id, level_sd, level_length_scale,
                                          run_nugget_sd);
    y_sim ~ multi_normal_cholesky(run_mean, cholesky_decompose(K_sim));
  } else {
    matrix[M + N, M + N] K = koh_joint_cov(xt_sim, w_sim, append_theta(x, theta_unit), w_top, x_delta,
                                           kernel_id, level_sd, level_length_scale,
                                           run_nugget_sd, rho, delta_sd, delta_length_scale,
                                           weighted_noise_variance(row_noise_variance(noise_sd, source, known_sd,
                                                                                      noise_log_scale, noise_loc),
                                                                   noise_weight));
    if (n_biased > 0) {  // the biases' covariance among the physical rows (source_bias.stan)
      K[(M + 1):(M + N), (M + 1):(M + N)] += source_bias_cov(x, bias_of, kernel_id, bias_sd, bias_length_scale);
    }
    vector[M + N] mu = append_row(run_mean, rho * (w_top * append_row(low_emulator_mean, emulator_mean))
                                            + h * beta);
    y_joint ~ multi_normal_cholesky(mu, cholesky_decompose(K));
  }
}
generated quantities {
  array[S] real noise_sd_original = to_array_1d(to_vector(noise_sd) * y_scale);
  array[use_discrepancy] real delta_sd_original;
  vector[noise_id == 3 ? N : 0] row_weight = noise_weight;  // Student-t: each row's weight in the fit (small: an outlier)
  vector[N] log_lik;      // log p(y_i | y_-i, runs, parameters), original units
  vector[N] y_rep;        // replicated data, original units
  vector[N] y_loo_mean;   // E(y_i | y_-i, runs, parameters), original units
  vector[N] delta_gp;     // GP part of the discrepancy at the physical points, original units
  vector[N] delta_gp_mean;  // its mean given the data, runs and parameters, original units
  vector[P] f_new;        // emulated simulator output at the prediction points
  vector[P] delta_new;    // discrepancy at the prediction points
  vector[P] zeta_new;     // true process rho * f + delta at the prediction points
  // each biased source's bias at the prediction points, original units (functions/source_bias.stan)
  matrix[n_biased, P] bias_new = rep_matrix(0, n_biased, P);
  if (use_discrepancy) delta_sd_original[1] = delta_sd[1] * y_scale;
  {
    // every level's GP and each run's weights, as in the model block
    matrix[L, L] w_level = fidelity_weights(level_rho);
    matrix[M, L] w_sim = w_level[run_level];
    row_vector[L] w_top = w_level[L];
    array[L] real level_sd = append_array(to_array_1d(low_emulator_sd), {emulator_sd});
    array[L, D + Q] real level_length_scale = append_array(low_emulator_length_scale, {emulator_length_scale});
    vector[M] run_nugget_sd = append_row(low_emulator_nugget, emulator_nugget)[run_level];
    vector[L] level_mean = append_row(low_emulator_mean, emulator_mean);
    vector[N] noise_var = row_noise_variance(noise_sd, source, known_sd, noise_log_scale, noise_loc);
    // the biases' covariances among the rows and at the prediction points, drawn jointly with f and delta
    // (source_bias.stan; koh_joint.stan)
    tuple(matrix[n_biased > 0 ? N : 0, n_biased > 0 ? N : 0], matrix[n_biased * P, N],
          matrix[n_biased * P, n_biased * P]) bias
      = source_bias_blocks(x, x_new, bias_of, kernel_id, bias_sd, bias_length_scale);
    tuple(vector[N], vector[N], vector[N], vector[N], vector[N], vector[P], vector[P], vector[P],
          vector[n_biased * P]) q
      = koh_joint_quantities_rng(y_sim, y, xt_sim, x, theta_unit, x_delta, h, beta, x_new, x_delta_new,
                                 h_new, normals_new, prior_only, kernel_id, w_sim, rep_matrix(w_top, N),
                                 rep_matrix(w_top, P), to_array_1d(level_mean),
                                 level_sd, level_length_scale, diag_matrix(square(run_nugget_sd)),
                                 rho, delta_sd, delta_length_scale, weighted_noise_variance(noise_var, noise_weight),
                                 0, bias, source_bias_normals_rng(bias_normals_new, n_biased, P),
                                 y_center, y_scale);
    log_lik = q.1;
    y_loo_mean = q.2;
    y_rep = q.3;
    delta_gp = q.4;
    delta_gp_mean = q.5;
    f_new = q.6;
    delta_new = q.7;
    zeta_new = q.8;
    bias_new = to_matrix(q.9, P, n_biased)';  // source by source (source_bias_blocks)
  }
}
