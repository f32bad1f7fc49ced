// Kennedy-O'Hagan calibration with a cheap simulator written in Stan
// (review section 4.1, eq. 6):
//   y_i = rho * f(x_i, theta) + delta(x_i, z_i) + eps_i,
//   delta = h(x_i, z_i)' beta + GP(0, ARD kernel), eps_i the measurement noise:
//   normal, one sd or one per source, plus any known sd, or Student-t
//   (functions/noise.stan); a reading by a biased source adds that source's
//   bias GP b_s(x_i) (functions/source_bias.stan).
// The GP may be restricted for an identifiable theta (section 6.3): orthogonal
// to df/dtheta (Plumlee 2017) or scaled (S-GaSP, Gu & Wang 2018); see
// functions/restricted_gp.stan.
// The mean terms h (H = 0 by default) carry a candidate unmodelled effect.
// With use_discrepancy = 0 it is plain Bayesian parameter estimation.
// Outputs are standardised inside: y = (y_original - y_center) / y_scale.
functions {
#include simulator.stan
#include simulator_output.stan
#include gp_kernels.stan
#include gp_conditional.stan
#include loo.stan
#include priors.stan
#include scaling.stan
#include restricted_gp.stan
#include given_normals.stan
#include noise.stan
#include source_bias.stan
}
data {
  int<lower=1> N;                       // number of physical observations
  int<lower=1> D;                       // number of simulator inputs
  int<lower=1> D_delta;                 // number of discrepancy inputs: simulator inputs, then covariates
  int<lower=1> Q;                       // number of calibration parameters
  matrix[N, D] X;                       // simulator inputs of the physical points, original units
  array[N] vector[D_delta] x_delta;     // discrepancy inputs of the physical points, scaled to [0, 1]
  vector[N] y;                          // physical output, standardised
  int<lower=0> H;                       // number of discrepancy mean terms (0 = zero mean)
  matrix[N, H] h;                       // mean terms at the physical points, scaled to unit RMS
  vector<lower=0>[H] beta_prior_sd;     // prior sd of each coefficient, standardised units
  real y_center;                        // original-scale y = y_center + y_scale * y
  real<lower=0> y_scale;                // see y_center
  vector[Q] theta_lower;                // lower bounds of theta, original units (uniform prior)
  vector<lower=theta_lower>[Q] theta_upper;  // upper bounds of theta, original units
  int<lower=0, upper=1> use_discrepancy;     // 1 = GP discrepancy, 0 = none
  int<lower=1, upper=3> discrepancy_form;    // 1 = GP, 2 = orthogonal GP, 3 = scaled GP
  int<lower=0> R;                       // quadrature nodes on the input box (orthogonal GP)
  matrix[R, D] X_quad;                  // the nodes, original units
  array[R] vector[D_delta] x_quad;      // the nodes, scaled like x_delta
  vector<lower=0>[R] w_quad;            // quadrature weights, summing to 1
  real<lower=0> scaled_lambda;          // scaled GP: penalty lambda_z on delta's mean square
  int<lower=1, upper=2> kernel_id;      // discrepancy kernel: 1 = squared exponential, 2 = Matern 5/2
  int<lower=0, upper=1> estimate_rho;   // 1 = estimate the KOH scale rho, 0 = rho fixed at 1
  int<lower=0, upper=1> prior_only;     // 1 = ignore y: draws from the prior
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
  int<lower=0> P;                       // number of prediction points
  matrix[P, D] X_new;                   // simulator inputs of the prediction points, original units
  array[P] vector[D_delta] x_delta_new; // discrepancy inputs of the prediction points, scaled to [0, 1]
  matrix[P, H] h_new;                   // mean terms at the prediction points, scaled like h
#include prediction_normals_data.stan
  matrix[P_normals, n_biased] bias_normals_new;  // as normals_new, for the bias curves at the prediction points
}
transformed data {
  int orthogonal = use_discrepancy && discrepancy_form == 2;
  int scaled = use_discrepancy && discrepancy_form == 3;
  // nodes U and number of functionals the GP is conditioned on (restricted_gp.stan)
  int U = orthogonal ? R : (scaled ? N : 0);
  int n_functionals = orthogonal ? Q : U;
  // R = 0 unless the GP is orthogonal
  array[U] vector[D_delta] x_U = scaled ? x_delta : x_quad;
  array[0] vector[D_delta] no_points = rep_array(rep_vector(0, D_delta), 0);  // the model block's prediction points
  check_given_normals(P_normals, P);
  // a GP integrated out of the likelihood: the discrepancy's, or biased sources' (source_bias.stan)
  int gp_integrated = use_discrepancy || n_biased > 0;
  // Student-t noise: the weights of its scale mixture are sampled where a GP is integrated out
  int n_weight = noise_id == 3 && gp_integrated ? N : 0;
  // the biases' inputs: the simulator inputs, scaled to [0, 1] (source_bias.stan)
  array[N] vector[D] x_bias;
  array[P] vector[D] x_bias_new;
  for (i in 1:N) x_bias[i] = x_delta[i][1:D];
  for (i in 1:P) x_bias_new[i] = x_delta_new[i][1:D];
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;                // theta rescaled to [0, 1]
  array[S] real<lower=0> noise_sd;                       // standardised units, one per source (S = 1 unless per_source);
                                                         // heteroscedastic: the sd's geometric mean over the settings
  array[noise_id == 3] real<lower=0> nu;                 // Student-t degrees of freedom
  vector<lower=0>[n_weight] noise_weight;                // Student-t scale-mixture weight of each row
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
  real rho = estimate_rho ? rho_free[1] : 1.0;
}
model {
  // theta_unit is uniform on [0, 1]: the bounds are the prior support.
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
    vector[N] resid = y - rho * standardized_simulator(X, theta, y_center, y_scale) - h * beta;
    vector[N] noise_var = row_noise_variance(noise_sd, source, known_sd, noise_log_scale, noise_loc);
    if (gp_integrated) {
      // the discrepancy's covariance at the points, then the biases' (source_bias.stan); without biased
      // sources the autodiff tape is the one of the program before them, so that its draws are unchanged
      matrix[N, N] K = rep_matrix(0, N, N);
      if (use_discrepancy) {
        // the restriction's map A (no rows: unrestricted) and ridge (restricted_gp.stan)
        matrix[U, n_functionals] A = U > 0 ? restriction_map(orthogonal, X_quad, w_quad, theta, theta_lower,
                                                             theta_upper, y_center, y_scale, N)
                                           : rep_matrix(0, U, n_functionals);
        real ridge = scaled ? square(delta_sd[1]) * N / scaled_lambda : 0;
        // the GP's covariance at the points, restricted when U > 0 (no prediction points here)
        K = restricted_gp_cov(x_delta, no_points, x_U, A, kernel_id, delta_sd[1], delta_length_scale, ridge).1;
      }
      if (n_biased > 0) K += source_bias_cov(x_bias, bias_of, kernel_id, bias_sd, bias_length_scale);
      resid ~ multi_normal_cholesky(rep_vector(0, N), cholesky_decompose(
        add_jitter(add_diag(K, weighted_noise_variance(noise_var, noise_weight)),
                   n_biased > 0 ? gp_variance(delta_sd, bias_sd) : square(delta_sd[1]))));
    } else {
      resid ~ independent_noise(noise_var, nu);
    }
  }
}
generated quantities {
  array[S] real noise_sd_original = to_array_1d(to_vector(noise_sd) * y_scale);
  array[use_discrepancy] real delta_sd_original;
  vector[noise_id == 3 ? N : 0] row_weight;  // Student-t: each row's weight in the fit (small: an outlier)
  vector[N] log_lik;      // log p(y_i | y_-i, parameters), original units
  vector[N] y_rep;        // replicated data, original units
  vector[N] y_loo_mean;   // E(y_i | y_-i, parameters), original units
  vector[N] delta_gp;     // GP part of the discrepancy at the physical points, original units
  vector[N] delta_gp_mean;  // its mean given the data and parameters, original units
  vector[P] f_new;        // simulator output at the prediction points
  vector[P] delta_new;    // discrepancy at the prediction points
  vector[P] zeta_new;     // true process rho * f + delta at the prediction points
  // each biased source's bias at the prediction points, original units (functions/source_bias.stan)
  matrix[n_biased, P] bias_new = rep_matrix(0, n_biased, P);
  {
    vector[N] f = standardized_simulator(X, theta, y_center, y_scale);
    vector[N] mean_terms = h * beta;
    vector[N] resid = y - rho * f - mean_terms;
    vector[N] noise_var = row_noise_variance(noise_sd, source, known_sd, noise_log_scale, noise_loc);
    vector[N] resid_loo_mean = rep_vector(0, N);
    vector[P] f_new_std = standardized_simulator(X_new, theta, y_center, y_scale);
    vector[N] delta_obs = rep_vector(0, N);
    vector[N] delta_obs_mean = rep_vector(0, N);
    vector[P] delta_new_std = rep_vector(0, P);
    vector[N] bias_obs = rep_vector(0, N);  // the biases at the rows (0 at a reference source's)
    if (gp_integrated) {
      matrix[N, N] K_delta = rep_matrix(0, N, N);
      matrix[P, N] K_cross = rep_matrix(0, P, N);
      matrix[P, P] K_new = rep_matrix(0, P, P);
      if (use_discrepancy) {
        delta_sd_original[1] = delta_sd[1] * y_scale;
        // the restriction's map A (no rows: unrestricted) and ridge (restricted_gp.stan)
        matrix[U, n_functionals] A = U > 0 ? restriction_map(orthogonal, X_quad, w_quad, theta, theta_lower,
                                                             theta_upper, y_center, y_scale, N)
                                           : rep_matrix(0, U, n_functionals);
        real ridge = scaled ? square(delta_sd[1]) * N / scaled_lambda : 0;
        // the GP's covariances at the points and the prediction points, restricted when U > 0
        tuple(matrix[N, N], matrix[P, N], matrix[P, P]) K_all = restricted_gp_cov(
          x_delta, x_delta_new, x_U, A, kernel_id, delta_sd[1], delta_length_scale,
          ridge);
        K_delta = K_all.1;
        K_cross = K_all.2;
        K_new = K_all.3;
      }
      // the biases' covariances among the rows and at the prediction points (source_bias.stan)
      tuple(matrix[n_biased > 0 ? N : 0, n_biased > 0 ? N : 0], matrix[n_biased * P, N],
            matrix[n_biased * P, n_biased * P]) bias
        = source_bias_blocks(x_bias, x_bias_new, bias_of, kernel_id, bias_sd, bias_length_scale);
      int n_bias_rows = rows(bias.1);  // N, or 0 without a biased source
      matrix[N, N] K_bias = n_biased > 0 ? bias.1 : rep_matrix(0, N, N);
      matrix[N, N] L = cholesky_decompose(add_jitter(
        add_diag(K_delta + K_bias, weighted_noise_variance(noise_var, noise_weight)), gp_variance(delta_sd, bias_sd)));
      tuple(vector[N], vector[N]) loo = mvn_loo(resid, L);
      log_lik = loo.1;
      resid_loo_mean = loo.2;
      // delta and the biases, at the rows and at the prediction points, each drawn jointly: given the data
      // they are correlated, so a biased reading's zeta + b_s (y_rep, predict()'s new readings) has its
      // sum's conditional spread; delta's draws are delta alone (what stancal gap reads)
      int n_delta = use_discrepancy ? N : 0;
      int p_delta = use_discrepancy ? P : 0;
      vector[P] z_new = use_discrepancy ? prediction_normals_rng(normals_new, 2, P) : rep_vector(0, P);
      vector[n_delta + n_bias_rows] at_rows = source_bias_joint_draw(
        resid, L, K_delta[1:n_delta], K_delta[1:n_delta, 1:n_delta], K_bias[1:n_bias_rows], bias.1,
        std_normals_rng(n_delta + n_bias_rows), prior_only);
      vector[p_delta + n_biased * P] at_new = source_bias_joint_draw(
        resid, L, K_cross[1:p_delta], K_new[1:p_delta, 1:p_delta], bias.2, bias.3,
        append_row(z_new[1:p_delta], source_bias_normals_rng(bias_normals_new, n_biased, P)), prior_only);
      if (use_discrepancy) {
        delta_obs = at_rows[1:N];
        delta_new_std = at_new[1:P];
        if (!prior_only) delta_obs_mean = gp_conditional_mean(resid, L, K_delta);
      }
      if (n_biased > 0) bias_obs = at_rows[(n_delta + 1):(n_delta + N)];
      bias_new = y_scale * to_matrix(at_new[(p_delta + 1):(p_delta + n_biased * P)], P, n_biased)';
    } else {
      log_lik = noise_log_lik(resid, noise_var, nu);
    }
    row_weight = outlier_weight(resid, noise_var, nu, noise_weight);
    log_lik -= log(y_scale);
    y_rep = y_center + y_scale * noise_rng(rho * f + mean_terms + delta_obs + bias_obs, noise_var, nu, noise_weight);
    y_loo_mean = y_center + y_scale * (y - resid + resid_loo_mean);
    delta_gp = y_scale * delta_obs;
    delta_gp_mean = y_scale * delta_obs_mean;
    f_new = y_center + y_scale * f_new_std;
    delta_new = y_scale * (h_new * beta + delta_new_std);
    zeta_new = y_center + y_scale * (rho * f_new_std + h_new * beta + delta_new_std);
  }
}
