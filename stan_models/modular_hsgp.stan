// Modular (two-stage) KOH calibration for thousands of runs and physical
// points (review sections 4.2 and 8.4): modular.stan's model with
// - the emulator from stancal.scalable_emulator, fixed after stage 1: its
//   mean at (x_i, theta) is the GP mean given all runs, interpolated in
//   theta by tensor Chebyshev polynomials through precomputed weights,
//     m_i(theta) = emulator_mean + weights_i . T(theta),
//   and its error at the points, correlated across them, as R leading
//   eigenvectors of its covariance (columns E, scaled by the square roots of
//   their eigenvalues) plus an independent variance v for the rest (data);
// - the discrepancy GP in its Hilbert-space approximation (Riutort-Mayol et
//   al. 2023), weights integrated out as in koh_hsgp.stan:
//   y_i = rho (m_i(theta) + E_i u) + h_i' beta + phi(x_i)' w + e_i,
//   u ~ N(0, I), e_i ~ N(0, noise_sd^2 + rho^2 v).
// The emulator's error weights u are integrated out with the discrepancy's
// w, as B + R basis functions. The mean is linear in K = 1 + G + H
// precomputed columns, so the residual's sums r' r and [Phi E]' r come from
// K x K and (B + R) x K data: each gradient costs O((B + R) K + K^2 + (B + R)^3),
// whatever the number of points.
functions {
#include gp_kernels.stan
#include chebyshev.stan
#include hsgp.stan
#include priors.stan
#include scaling.stan
#include given_normals.stan
}
data {
  int<lower=1> N;                       // number of physical observations
  int<lower=1> D;                       // number of simulator inputs
  int<lower=1> D_delta;                 // number of discrepancy inputs: simulator inputs, then covariates
  int<lower=1> Q;                       // number of calibration parameters
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
  int<lower=1, upper=2> kernel_id;      // discrepancy kernel: 1 = squared exponential, 2 = Matern 5/2
  int<lower=0, upper=1> estimate_rho;   // 1 = estimate the KOH scale rho, 0 = rho fixed at 1
  int<lower=0, upper=1> prior_only;     // 1 = ignore y: draws from the prior
  int<lower=1> B;                       // number of basis functions
  array[B, D_delta] int<lower=1> basis_index;  // eigenfunction number per input of each
  vector<lower=0.5>[D_delta] boundary;  // L per input: the basis lives on [0.5 - L, 0.5 + L]
  array[D] real<lower=0> longest_length_scale;  // per simulator input: what the boundary represents
  // the stage-1 emulator (stancal.scalable_emulator), standardised units
  real emulator_mean;                   // the emulator's constant mean
  array[Q] int<lower=0> theta_degree;   // Chebyshev degree per parameter
  int<lower=1> G;                       // prod(theta_degree + 1)
  matrix[N, G] emulator_weights;        // m_i(theta) = emulator_mean + row i . T(theta)
  int<lower=0> emulator_error_rank;     // R: eigenvectors of the emulator error's covariance at the points
  matrix[N, emulator_error_rank] emulator_error_basis;  // E: E E' + v I approximates that covariance
  real<lower=0> emulator_variance;      // v: what E leaves of each point's variance, averaged
  int<lower=0> P;                       // number of prediction points
  array[P] vector[D_delta] x_delta_new; // discrepancy inputs of the prediction points, scaled to [0, 1]
  matrix[P, H] h_new;                   // mean terms at the prediction points, scaled like h
  matrix[P, G] emulator_weights_new;    // the emulator mean's weights at the prediction points
#include basis_normals_data.stan
}
transformed data {
  int R = emulator_error_rank;
  int B_delta = use_discrepancy ? B : 0;
  int W = B_delta + R;                  // basis weights integrated out: discrepancy's, then emulator error's
  matrix[N, B] phi = hsgp_basis(x_delta, basis_index, boundary);
  matrix[N, W] basis = append_col(phi[:, 1:B_delta], emulator_error_basis);
  matrix[W, N] basis_t = basis';
  matrix[W, W] basis_t_basis = crossprod(basis);
  check_given_normals(B_normals, B + R);
  // mean = columns * coefficients(theta, rho, beta): the residual's sums from these
  matrix[N, 1 + G + H] columns = append_col(append_col(rep_vector(1, N), emulator_weights), h);
  matrix[1 + G + H, 1 + G + H] columns_t_columns = crossprod(columns);
  vector[1 + G + H] columns_t_y = columns' * y;
  matrix[W, 1 + G + H] basis_t_columns = basis_t * columns;
  vector[W] basis_t_y = basis_t * y;
  real y_t_y = dot_self(y);
}
parameters {
  vector<lower=0, upper=1>[Q] theta_unit;                // theta rescaled to [0, 1]
  real<lower=0> noise_sd;                                // standardised units
  array[use_discrepancy] real<lower=0> delta_sd;         // standardised units
  // simulator inputs, fraction of the input's range (the basis caps it at longest_length_scale)
  array[use_discrepancy ? D : 0] real<lower=0> delta_input_length_scale;
  array[use_discrepancy ? D_delta - D : 0] real<lower=0> delta_relevance;  // covariates: inverse length scale
  array[estimate_rho] real<lower=0> rho_free;
  vector[H] beta;                                        // mean-term coefficients, standardised units
}
transformed parameters {
  array[use_discrepancy ? D_delta : 0] real delta_length_scale
    = discrepancy_length_scales(delta_input_length_scale, delta_relevance);
  vector[Q] theta = theta_from_unit(theta_unit, theta_lower, theta_upper);
  real rho = estimate_rho ? rho_free[1] : 1.0;
}
model {
  // theta_unit is uniform on [0, 1]: the bounds are the prior support.
  noise_sd ~ observation_noise_sd();                 // half-normal(0, 1)
  delta_sd ~ discrepancy_sd();                       // half-normal(0, 0.5)
  delta_input_length_scale ~ discrepancy_length_scale();  // inverse gamma(3, 1)
  delta_relevance ~ covariate_relevance();           // half-normal(0, 2)
  rho_free ~ koh_scale();                            // normal(1, 0.25), rho > 0
  beta ~ normal(0, beta_prior_sd);
  if (!prior_only) {
    vector[1 + G + H] coefficients
      = append_row(rho * append_row(emulator_mean, chebyshev_tensor_basis(theta_unit, theta_degree)), beta);
    real rtr = y_t_y - 2 * dot_product(columns_t_y, coefficients) + quad_form(columns_t_columns, coefficients);
    real error_var = square(noise_sd) + square(rho) * emulator_variance;
    if (W > 0) {
      vector[W] weight_sd = rep_vector(rho, W);  // the emulator error's columns carry their eigenvalues
      if (use_discrepancy) {
        weight_sd[1:B] = hsgp_weight_sd(basis_index, boundary, kernel_id, delta_sd[1], delta_length_scale,
                                        longest_length_scale);
      }
      target += hsgp_marginal_from_sums(rtr, basis_t_y - basis_t_columns * coefficients, N, basis_t_basis,
                                        weight_sd, error_var);
    } else {
      target += -0.5 * rtr / error_var - 0.5 * N * log(2 * pi() * error_var);
    }
  }
}
generated quantities {
  real noise_sd_original = noise_sd * y_scale;
  array[use_discrepancy] real delta_sd_original;
  vector[use_discrepancy ? B : 0] delta_basis_weights;  // the discrepancy's weights, standardised units
  vector[N] log_lik;      // log p(y_i | parameters, basis weights, emulator), original units
  vector[N] y_rep;        // replicated data, original units
  vector[N] y_loo_mean;   // E(y_i | parameters, basis weights): PSIS-LOO weights make it held out
  vector[N] delta_gp;     // GP part of the discrepancy at the physical points, original units
  // the emulator error's basis weights u: its error at the points is rho * E u (standardised units)
  vector[emulator_error_rank] emulator_error_weights;
  vector[P] f_new;        // emulator mean at the prediction points
  vector[P] delta_new;    // discrepancy at the prediction points
  vector[P] zeta_new;     // true process rho * f + delta at the prediction points
  {
    vector[G] chebyshev = chebyshev_tensor_basis(theta_unit, theta_degree);
    real error_var = square(noise_sd) + square(rho) * emulator_variance;
    vector[N] mu = rho * (emulator_mean + emulator_weights * chebyshev) + h * beta;
    vector[N] delta_obs = rep_vector(0, N);
    vector[P] delta_new_std = rep_vector(0, P);
    vector[N] error_obs = rep_vector(0, N);
    emulator_error_weights = rep_vector(0, R);
    delta_basis_weights = rep_vector(0, B_delta);
    if (W > 0) {
      vector[W] weight_sd = rep_vector(rho, W);
      if (use_discrepancy) {
        weight_sd[1:B] = hsgp_weight_sd(basis_index, boundary, kernel_id, delta_sd[1], delta_length_scale,
                                        longest_length_scale);
      }
      vector[B + R] normals = B_normals ? basis_normals : to_vector(normal_rng(rep_vector(0, B + R), 1));
      vector[W] z = append_row(normals[1:B_delta], normals[(B + 1):(B + R)]);
      // a prior draw, or one from the weights' conditional given the data
      vector[W] weights = prior_only ? weight_sd .* z
                          : hsgp_weights(y - mu, basis_t, basis_t_basis, weight_sd, error_var, z);
      delta_basis_weights = weights[1:B_delta];
      emulator_error_weights = weights[(B_delta + 1):W];
      error_obs = rho * (emulator_error_basis * emulator_error_weights);
    }
    if (use_discrepancy) {
      delta_sd_original[1] = delta_sd[1] * y_scale;
      delta_obs = phi * delta_basis_weights;
      if (P > 0) delta_new_std = hsgp_basis(x_delta_new, basis_index, boundary) * delta_basis_weights;
    }
    mu += delta_obs + error_obs;
    real sd_obs = sqrt(error_var);
    for (i in 1:N) log_lik[i] = normal_lpdf(y[i] | mu[i], sd_obs) - log(y_scale);
    y_rep = y_center + y_scale * to_vector(normal_rng(mu, sd_obs));
    y_loo_mean = y_center + y_scale * mu;
    delta_gp = y_scale * delta_obs;
    vector[P] f_new_std = emulator_mean + emulator_weights_new * chebyshev;
    f_new = y_center + y_scale * f_new_std;
    delta_new = y_scale * (h_new * beta + delta_new_std);
    zeta_new = y_center + y_scale * (rho * f_new_std + h_new * beta + delta_new_std);
  }
}
