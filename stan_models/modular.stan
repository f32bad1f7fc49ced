// Modular (two-stage) KOH calibration with an expensive simulator
// (Bayarri et al. 2007b; Liu et al. 2009; review section 4.2). The emulator
// hyperparameters come fixed from stage 1 (emulator.stan), which cuts the
// feedback from the physical data into the emulator. Given the runs, the
// emulator at (x_i, theta) is normal with mean m(theta) and covariance
// V(theta); V is carried into the likelihood:
//   y ~ N(rho * m(theta) + h' beta, rho^2 (V(theta) + nugget^2 S) + K_delta + diag(noise variances)),
//   S_ij = 1 where points i and j are one (the emulator's misfit there, below; f_new and y_rep
//   carry it too, functions/koh_joint.stan),
// with the measurement noise of functions/noise.stan (Student-t: given its mixture weights),
// and each biased source's bias GP beside K_delta (functions/source_bias.stan),
// with optional discrepancy mean terms h (a candidate unmodelled effect).
// The runs may come from simulators of several fidelities, cheapest first
// (Kennedy & O'Hagan 2000; fidelity.stan): the emulator of the calibrated,
// top level then learns from the cheaper runs too.
// The emulator's nugget (the part of the runs a smooth GP misses) is part of
// its uncertainty at the physical points too (Higdon et al. 2008). A
// stochastic simulator's runs add their own intrinsic variance on the runs'
// diagonal only, and its replicates share one nugget: the emulator is of the
// simulator's MEAN (stochastic kriging, Ankenman, Nelson & Staum 2010), and
// reality's own scatter is the noise model's job (Baker et al. 2022).
functions {
#include gp_kernels.stan
#include gp_conditional.stan
#include noise.stan
#include fidelity.stan
#include fidelity_theta.stan
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
  int<lower=0> Q_low;                   // the cheapest level's own theta_l (Goh et al. 2013): how many; 0 = theta shared
  vector[Q_low] theta_low_lower;        // lower bounds of theta_l, original units (uniform prior)
  vector<lower=theta_low_lower>[Q_low] theta_low_upper;  // upper bounds of theta_l, original units
  array[M] vector[Q + Q_low] theta_sim; // (theta, theta_l) of the runs, scaled to [0, 1] within their bounds
                                        // (the parameters a run's simulator lacks: any value, unused)
  vector[M] y_sim;                      // simulator output of the runs, standardised like y
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
  int<lower=0, upper=1> prior_only;     // 1 = ignore y (the runs still inform the emulator)
  int<lower=1> L;                       // fidelity levels of the runs: 1 = the calibrated simulator only
  array[M] int<lower=1, upper=L> run_level;  // each run's level: 1 the cheapest, L the calibrated simulator
  vector[L - 1] level_rho;              // stage 1: each level's scale on the level below (its intercept: at x = 0)
  matrix[L - 1, D] level_rho_slope;     // stage 1: its slopes on the inputs, unit cube: rho_k(x) = level_rho[k - 1]
                                        // + level_rho_slope[k - 1] * x (Le Gratiet & Garnier 2014); zeros: constant
  array[L] real emulator_mean;          // stage-1 hyperparameters of each level's GP, standardised units
  array[L] real<lower=0> emulator_sd;   // see emulator_mean
  array[L, D + Q + Q_low] real<lower=0> emulator_length_scale;  // inputs, theta, theta_l; unit-cube units
  array[L] real<lower=0> emulator_nugget;  // see emulator_mean
  vector<lower=0>[M] run_intrinsic_sd;  // stochastic simulator: each run's intrinsic sd, standardised (0 = deterministic)
  int<lower=0> P;                       // number of prediction points
  array[P] vector[D] x_new;             // simulator inputs of the prediction points, scaled to [0, 1]
  array[P] vector[D_delta] x_delta_new; // discrepancy inputs of the prediction points, scaled to [0, 1]
  matrix[P, H] h_new;                   // mean terms at the prediction points, scaled like h
#include prediction_normals_data.stan
  matrix[P_normals, n_biased] bias_normals_new;  // as normals_new, for the bias curves at the prediction points
}
transformed data {
  array[M] vector[D + Q + Q_low] xt_sim;
  for (j in 1:M) xt_sim[j] = append_row(x_sim[j], theta_sim[j]);
  // each run's weights on the levels' GPs at its inputs; the physical and prediction points are at the top level
  matrix[M, L] w_sim = fidelity_point_weights(level_rho, level_rho_slope, x_sim, run_level);
  matrix[N, L] w_obs = fidelity_point_weights(level_rho, level_rho_slope, x, rep_array(L, N));
  matrix[P, L] w_new = fidelity_point_weights(level_rho, level_rho_slope, x_new, rep_array(L, P));
  row_vector[L] w_top = fidelity_widest(w_obs, emulator_sd);  // the jitter's scale
  // each run's own covariance: its level's nugget, one draw per setting for a stochastic simulator's
  // replicates, and their intrinsic variance on the diagonal (functions/same_point.stan)
  matrix[M, M] run_own = run_own_cov(replicated_runs(xt_sim, run_level, run_intrinsic_sd),
                                     to_vector(emulator_nugget)[run_level], run_intrinsic_sd);
  // the emulator's misfit at the physical points: the top level's nugget where two points are one
  // (Higdon et al. 2008), not the intrinsic variance
  matrix[N, N] nugget_obs = square(emulator_nugget[L]) * same_point(x);
  vector[N] top_mean = w_obs * to_vector(emulator_mean);  // the top level's prior mean at each point
  real top_variance = fidelity_variance(w_top, emulator_sd);
  matrix[M, M] L_sim = cholesky_decompose(
    fidelity_run_cov(xt_sim, w_sim, w_top, kernel_id, emulator_sd, emulator_length_scale, run_own));
  vector[M] alpha_sim = mdivide_right_tri_low(
    mdivide_left_tri_low(L_sim, y_sim - w_sim * to_vector(emulator_mean))', L_sim)';
  // the physical points share theta, so the emulator's covariance among them
  // has no theta part: data. Squared exponential: the points' covariance with
  // the runs factorises, level by level, into an x part (data here) and a
  // theta part (theta_factor).
  matrix[N, N] K_obs = fidelity_cov(x, w_obs, kernel_id, emulator_sd, emulator_length_scale[:, 1:D]);
  array[L] matrix[N, M] K_obs_sim_x;
  for (j in 1:L) {
    K_obs_sim_x[j] = diag_pre_multiply(col(w_obs, j), diag_post_multiply(
      gp_exp_quad_cov(x, x_sim, emulator_sd[j], emulator_length_scale[j, 1:D]), col(w_sim, j)));
  }
  check_given_normals(P_normals, P);
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;                // theta rescaled to [0, 1]
  vector<lower=0, upper=1>[Q_low] theta_low_unit;        // the cheapest level's own theta_l rescaled to [0, 1]
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
  array[n_biased] real<lower=0> bias_sd;                 // each biased source's bias GP marginal sd, standardised units
  array[n_biased, D] real<lower=0> bias_length_scale;    // its length scales: fraction of each input's range
}
transformed parameters {
  // heteroscedastic: the log noise sd's GP at the distinct settings, before centring (functions/noise.stan)
  vector[N_loc] noise_log_scale = noise_log_scale_at(x_noise, noise_gp_sd, noise_length_scale, noise_z);
  // the discrepancy's length scales over all its inputs: a covariate's is 1 / relevance
  array[use_discrepancy ? D_delta : 0] real delta_length_scale
    = discrepancy_length_scales(delta_input_length_scale, delta_relevance);
  vector[Q] theta = theta_from_unit(theta_unit, theta_lower, theta_upper);
  vector[Q_low] theta_low = theta_from_unit(theta_low_unit, theta_low_lower, theta_low_upper);
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
  bias_sd ~ discrepancy_sd();                        // half-normal(0, 0.5), as delta's
  to_array_1d(bias_length_scale) ~ discrepancy_length_scale();  // inverse gamma(3, 1), as delta's
  if (!prior_only) {
    tuple(vector[N], matrix[N, N]) emulated;  // the top level's mean and covariance at the points
    if (Q_low == 0) {  // the runs' covariance is data
      matrix[N, M] K_obs_sim;
      if (kernel_id == 1) {  // the first level assigned, the others added: one pass for one fidelity
        K_obs_sim = diag_post_multiply(K_obs_sim_x[1], theta_factor(theta_unit, theta_sim,
                                                                    emulator_length_scale[1, (D + 1):(D + Q)]));
        for (j in 2:L) {
          K_obs_sim += diag_post_multiply(K_obs_sim_x[j], theta_factor(theta_unit, theta_sim,
                                                                       emulator_length_scale[j, (D + 1):(D + Q)]));
        }
      } else {
        K_obs_sim = fidelity_cross_cov(append_theta(x, theta_unit), w_obs, xt_sim, w_sim, kernel_id, emulator_sd,
                                       emulator_length_scale);
      }
      emulated = fidelity_at_points(K_obs_sim, L_sim, alpha_sim, top_mean, K_obs);
    } else {  // theta_l moves the expensive runs' cheap part (functions/fidelity_theta.stan)
      // the runs condition the emulator at theta_l; their own density p(y_sim | theta_l) is left out, as
      // stage 2 leaves out the runs' density everywhere (docs/multifidelity.md: a choice, with its cost)
      array[M] vector[D + Q + Q_low] xt_run = runs_at_theta_low(x_sim, theta_sim, run_level, theta_low_unit);
      matrix[M, M] L_run = cholesky_decompose(
        fidelity_run_cov(xt_run, w_sim, w_top, kernel_id, emulator_sd, emulator_length_scale, run_own));
      vector[M] alpha_run = mdivide_right_tri_low(
        mdivide_left_tri_low(L_run, y_sim - w_sim * to_vector(emulator_mean))', L_run)';
      emulated = fidelity_at_points(
        fidelity_points_runs_cov(K_obs_sim_x, x, append_row(theta_unit, theta_low_unit), xt_run, w_obs, w_sim,
                                 kernel_id, emulator_sd, emulator_length_scale),
        L_run, alpha_run, top_mean, K_obs);
    }
    vector[N] emulator_mean_obs = emulated.1;
    matrix[N, N] K = square(rho) * (emulated.2 + nugget_obs);
    if (use_discrepancy) {
      K += ard_cov(x_delta, kernel_id, delta_sd[1], delta_length_scale);
    }
    if (n_biased > 0) K += source_bias_cov(x, bias_of, kernel_id, bias_sd, bias_length_scale);
    vector[N] noise_var = weighted_noise_variance(
      row_noise_variance(noise_sd, source, known_sd, noise_log_scale, noise_loc), noise_weight);
    y ~ multi_normal_cholesky(rho * emulator_mean_obs + h * beta,
                              cholesky_decompose(add_jitter(add_diag(K, noise_var),
                                                            square(rho) * top_variance)));
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
    vector[N] noise_var = row_noise_variance(noise_sd, source, known_sd, noise_log_scale, noise_loc);
    // the biases' covariances among the rows and at the prediction points, drawn jointly with f and delta
    // (source_bias.stan; koh_joint.stan)
    tuple(matrix[n_biased > 0 ? N : 0, n_biased > 0 ? N : 0], matrix[n_biased * P, N],
          matrix[n_biased * P, n_biased * P]) bias
      = source_bias_blocks(x, x_new, bias_of, kernel_id, bias_sd, bias_length_scale);
    array[M] vector[D + Q + Q_low] xt_run = Q_low == 0 ? xt_sim : runs_at_theta_low(x_sim, theta_sim, run_level,
                                                                                      theta_low_unit);
    tuple(vector[N], vector[N], vector[N], vector[N], vector[N], vector[P], vector[P], vector[P],
          vector[n_biased * P]) q
      = koh_joint_quantities_rng(y_sim, y, xt_run, x, append_row(theta_unit, theta_low_unit), x_delta, h, beta,
                                 x_new, x_delta_new, h_new, normals_new, prior_only, kernel_id, w_sim, w_obs, w_new,
                                 emulator_mean,
                                 emulator_sd, emulator_length_scale, run_own, rho, delta_sd,
                                 delta_length_scale, weighted_noise_variance(noise_var, noise_weight),
                                 square(emulator_nugget[L]), bias, source_bias_normals_rng(bias_normals_new, n_biased, P),
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
