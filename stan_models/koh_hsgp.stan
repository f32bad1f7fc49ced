// Kennedy-O'Hagan calibration with a cheap simulator written in Stan, for
// thousands of physical points (review section 8.4): koh.stan's model with
// the discrepancy GP replaced by its Hilbert-space approximation
// (Riutort-Mayol et al. 2023),
//   y_i = rho * f(x_i, theta) + h_i' beta + phi(x_i)' w + eps_i,
//   w_b ~ N(0, S(omega_b)),  S = the kernel's spectral density,
// with the weights w integrated out (hsgp_marginal_lpdf), so each gradient
// costs O(N B + B^3) for B basis functions, not O(N^3); generated
// quantities draw w from its conditional.
// The basis (B, basis_index, boundary) is chosen by stancal.hsgp from the
// length scales it has to represent, and checked against the fitted ones.
// Outputs are standardised inside: y = (y_original - y_center) / y_scale.
functions {
#include simulator.stan
#include simulator_output.stan
#include gp_kernels.stan
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
  int<lower=1, upper=2> kernel_id;      // discrepancy kernel: 1 = squared exponential, 2 = Matern 5/2
  int<lower=0, upper=1> estimate_rho;   // 1 = estimate the KOH scale rho, 0 = rho fixed at 1
  int<lower=0, upper=1> prior_only;     // 1 = ignore y: draws from the prior
  int<lower=1> B;                       // number of basis functions
  array[B, D_delta] int<lower=1> basis_index;  // eigenfunction number per input of each
  vector<lower=0.5>[D_delta] boundary;  // L per input: the basis lives on [0.5 - L, 0.5 + L]
  array[D] real<lower=0> longest_length_scale;  // per simulator input: what the boundary represents
  int<lower=0> P;                       // number of prediction points
  matrix[P, D] X_new;                   // simulator inputs of the prediction points, original units
  array[P] vector[D_delta] x_delta_new; // discrepancy inputs of the prediction points, scaled to [0, 1]
  matrix[P, H] h_new;                   // mean terms at the prediction points, scaled like h
#include basis_normals_data.stan
}
transformed data {
  matrix[N, B] phi = hsgp_basis(x_delta, basis_index, boundary);
  matrix[B, N] phi_t = phi';
  matrix[B, B] phi_t_phi = crossprod(phi);
  check_given_normals(B_normals, B);
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
    vector[N] resid = y - rho * standardized_simulator(X, theta, y_center, y_scale) - h * beta;
    if (use_discrepancy) {
      resid ~ hsgp_marginal(phi_t, phi_t_phi,
                            hsgp_weight_sd(basis_index, boundary, kernel_id, delta_sd[1],
                                           delta_length_scale, longest_length_scale),
                            square(noise_sd));
    } else {
      resid ~ normal(0, noise_sd);
    }
  }
}
generated quantities {
  real noise_sd_original = noise_sd * y_scale;
  array[use_discrepancy] real delta_sd_original;
  vector[use_discrepancy ? B : 0] delta_basis_weights;  // the discrepancy's weights, standardised units
  vector[N] log_lik;      // log p(y_i | parameters, basis weights), original units
  vector[N] y_rep;        // replicated data, original units
  vector[N] y_loo_mean;   // E(y_i | parameters, basis weights): PSIS-LOO weights make it held out
  vector[N] delta_gp;     // GP part of the discrepancy at the physical points, original units
  vector[P] f_new;        // simulator output at the prediction points
  vector[P] delta_new;    // discrepancy at the prediction points
  vector[P] zeta_new;     // true process rho * f + delta at the prediction points
  {
    vector[N] mu = rho * standardized_simulator(X, theta, y_center, y_scale) + h * beta;
    vector[N] delta_obs = rep_vector(0, N);
    vector[P] delta_new_std = rep_vector(0, P);
    if (use_discrepancy) {
      delta_sd_original[1] = delta_sd[1] * y_scale;
      vector[B] weight_sd = hsgp_weight_sd(basis_index, boundary, kernel_id, delta_sd[1],
                                           delta_length_scale, longest_length_scale);
      vector[B] z = B_normals ? basis_normals : to_vector(normal_rng(rep_vector(0, B), 1));
      // a prior draw, or one from the weights' conditional given the data
      delta_basis_weights = prior_only ? weight_sd .* z
                            : hsgp_weights(y - mu, phi_t, phi_t_phi, weight_sd, square(noise_sd), z);
      delta_obs = phi * delta_basis_weights;
      if (P > 0) delta_new_std = hsgp_basis(x_delta_new, basis_index, boundary) * delta_basis_weights;
    }
    mu += delta_obs;
    for (i in 1:N) log_lik[i] = normal_lpdf(y[i] | mu[i], noise_sd) - log(y_scale);
    y_rep = y_center + y_scale * to_vector(normal_rng(mu, noise_sd));
    y_loo_mean = y_center + y_scale * mu;
    delta_gp = y_scale * delta_obs;
    vector[P] f_new_std = standardized_simulator(X_new, theta, y_center, y_scale);
    f_new = y_center + y_scale * f_new_std;
    delta_new = y_scale * (h_new * beta + delta_new_std);
    zeta_new = y_center + y_scale * (rho * f_new_std + h_new * beta + delta_new_std);
  }
}
