// Kennedy-O'Hagan calibration from simulator runs with latent GPs, for
// non-Gaussian or censored outputs and functional theta (see koh_latent.stan
// for the cheap-simulator version of the same model):
//   g(E[y_i]) = f(x_i, theta(x_i)) + h(x_i, z_i)' beta + delta(x_i, z_i),
//   f ~ GP(emulator_mean, ARD kernel over (x, theta)) on the link scale,
//   trained on the runs g(y_sim_j) = f(x_sim_j, theta_sim_j) + nugget_j.
// As in modular.stan, the emulator's hyperparameters come fixed from stage 1
// (emulator.stan): sampled with latent GPs they leave a geometry NUTS cannot
// follow (a vanishing nugget, unbounded length scales of inputs the simulator
// ignores). The emulator's values at the physical points are a latent draw
// given the runs (functions/latent_gp.stan), sampled with theta and delta, so
// its uncertainty there is carried into the fit.
// Inputs and theta are scaled to [0, 1]; the runs' link-scale outputs are
// standardised, and so are Gaussian physical outputs.
functions {
#include gp_kernels.stan
#include gp_conditional.stan
#include fidelity.stan
#include same_point.stan
#include koh_joint.stan
#include loo.stan
#include latent_gp.stan
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
  int<lower=1> M;                       // number of simulator runs
  int<lower=1> D;                       // number of simulator inputs
  int<lower=1> D_delta;                 // number of discrepancy inputs: simulator inputs, then covariates
  int<lower=1> Q;                       // number of calibration parameters
  array[N] vector[D] x;                 // simulator inputs of the physical points, scaled to [0, 1]
  array[N] vector[D_delta] x_delta;     // discrepancy inputs of the physical points, scaled to [0, 1]
  array[M] vector[D] x_sim;             // simulator inputs of the runs, scaled to [0, 1]
  array[M] vector[Q] theta_sim;         // theta of the runs, scaled to [0, 1] within its bounds
  vector[M] y_sim;                      // runs' output on the link scale, standardised: (g(y) - y_center) / y_scale
  int<lower=1, upper=4> likelihood_id;  // 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
  vector[N] y_real;                     // gaussian: output, standardised like y_sim (0 where censored or not gaussian)
  array[N] int<lower=0> y_int;          // poisson, negbinomial: counts; binomial: successes (else 0)
  array[N] int<lower=0> trials;         // binomial: number of trials (else 0)
  array[N] int<lower=0, upper=3> censoring;  // 0 = observed, 1 = left, 2 = right, 3 = interval
  vector[N] lower_bound;                // censoring bounds, standardised like y_real (used where censored)
  vector[N] upper_bound;                // see lower_bound
  real emulator_mean;                   // stage-1 emulator hyperparameters, standardised units
  real<lower=0> emulator_sd;            // see emulator_mean
  array[D + Q] real<lower=0> emulator_length_scale;  // inputs first, then theta; unit-cube units
  real<lower=0> emulator_nugget;        // see emulator_mean
  real y_center;                        // link-scale runs output = y_center + y_scale * y_sim
  real<lower=0> y_scale;                // see y_center
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
  int<lower=0, upper=1> delta_centred;  // 1 = sample the discrepancy's values, 0 = their standard normals
  int<lower=0> G;                       // number of grid points for the theta(x) curves
  array[G] vector[D_fun] x_fun_grid;    // the grid, scaled like x_fun
  int<lower=0, upper=1> prior_only;     // 1 = ignore y (the runs still inform the emulator)
  int<lower=0> P;                       // number of prediction points
  array[P] vector[D] x_new;             // simulator inputs of the prediction points, scaled to [0, 1]
  array[P] vector[D_delta] x_delta_new; // discrepancy inputs of the prediction points, scaled to [0, 1]
  array[P] vector[D_fun] x_fun_new;     // functional inputs of the prediction points, scaled like x_fun
  matrix[P, H] h_new;                   // mean terms at the prediction points, scaled like h
  array[P] int<lower=0> trials_new;     // binomial: trials of a new observation at each prediction point
#include functional_prediction_normals_data.stan
}
transformed data {
  // for the leave-one-out densities with the left-out discrepancy integrated out
  tuple(vector[20], vector[20]) loo_rule = normal_quadrature(20);
  array[M] vector[D + Q] xt_sim;
  for (j in 1:M) xt_sim[j] = append_row(x_sim[j], theta_sim[j]);
  array[0] real no_discrepancy = rep_array(0.0, 0);  // koh_joint_predict draws f alone with it
  matrix[M, 1] w_sim = rep_matrix(1, M, 1);  // one fidelity: every run on the one GP (fidelity.stan)
  row_vector[1] w_top = [1];
  matrix[M, M] L_sim = cholesky_decompose(
    emulator_run_cov(xt_sim, kernel_id, emulator_sd, emulator_length_scale, emulator_nugget));
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
  vector[H] beta;                                         // mean-term coefficients, model-scale units
  vector<lower=0>[F] theta_function_sd;                   // logit scale
  array[F] vector<lower=0>[D_fun] theta_function_length_scale;  // fraction of input range
  matrix[N_fun, F] theta_function_raw;    // its logit at x_fun (centred) or their standard normals
  vector[N] emulator_z;                                   // non-centred emulator at the physical points
}
transformed parameters {
  // logit of functional theta (unit scale) at x_fun
  matrix[N_fun, F] theta_function_logit = functional_logit_values(
    theta_function_raw, functional_centred, theta_unit, functional_slot, x_fun, kernel_id, theta_function_sd,
    theta_function_length_scale);
  // the discrepancy's length scales over all its inputs: a covariate's is 1 / relevance
  array[use_discrepancy ? D_delta : 0] real delta_length_scale
    = discrepancy_length_scales(delta_input_length_scale, delta_relevance);
  // theta at each physical point on [0, 1] (one row when none is functional)
  matrix[F > 0 ? N : 1, Q] theta_points_unit = theta_unit_rows(
    theta_unit, functional_slot, theta_function_logit[fun_point]);
  vector[Q] theta;                      // scalar theta; a functional one's mean over the points
  for (j in 1:Q) {
    theta[j] = theta_lower[j] + (theta_upper[j] - theta_lower[j]) * mean(theta_points_unit[:, j]);
  }
  array[N] vector[D + Q] xt_obs;        // emulator inputs of the physical points
  for (i in 1:N) xt_obs[i] = append_row(x[i], theta_points_unit[F > 0 ? i : 1]');
  // the emulator at the physical points, standardised
  vector[N] f_std = emulator_latent(L_sim, xt_sim, y_sim, xt_obs, kernel_id, emulator_mean, emulator_sd,
                                    emulator_length_scale, emulator_z);
  vector[N] delta = rep_vector(0, N);   // discrepancy at the physical points, model scale
  if (use_discrepancy) {
    delta = latent_gp_values(delta_raw, delta_centred, x_delta, kernel_id, delta_sd[1], delta_length_scale);
  }
}
model {
  noise_sd ~ observation_noise_sd();                 // half-normal(0, 1)
  inv_sqrt_phi ~ overdispersion();                   // half-normal(0, 1)
  delta_sd ~ discrepancy_sd();                       // half-normal(0, 0.5)
  delta_input_length_scale ~ discrepancy_length_scale();  // inverse gamma(3, 1)
  delta_relevance ~ covariate_relevance();           // half-normal(0, 2)
  // the discrepancy's GP (centred) or its standard normals (non-centred)
  if (use_discrepancy) {
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
  emulator_z ~ std_normal();
  if (!prior_only) {
    vector[N] eta = link_from_standardised(likelihood_id, f_std, y_center, y_scale) + h * beta + delta;
    target += sum(observation_log_lik(
      likelihood_id, eta, observation_sd(likelihood_id, noise_sd), negbinomial_precision(likelihood_id, inv_sqrt_phi),
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
  vector[P] f_new;        // emulated simulator mean at the prediction points, response scale
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
    // the linear predictor without the discrepancy GP
    vector[N] eta_rest = link_from_standardised(likelihood_id, f_std, y_center, y_scale) + h * beta;
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
    array[P] vector[D + Q] xt_new;
    for (i in 1:P) xt_new[i] = append_row(x_new[i], theta_new_unit[i]');
    // f at the new points given the runs and its latent values at the physical points
    // (noise-free: koh_joint_cov's jitter is the latent draw's)
    vector[P] f_std_new = rep_vector(emulator_mean, P);
    if (P > 0) {
      vector[M + N] resid = append_row(y_sim, f_std) - emulator_mean;
      matrix[M + N, M + N] L = cholesky_decompose(koh_joint_cov(
        xt_sim, w_sim, xt_obs, w_top, x_delta, kernel_id, {emulator_sd}, {emulator_length_scale},
        rep_vector(emulator_nugget, M), 1.0, no_discrepancy, no_discrepancy, rep_vector(0, N)));
      // the delta half of the draw is empty here (no discrepancy): its normals are zeros
      f_std_new += koh_joint_predict(resid, L, xt_sim, xt_obs, x_delta, xt_new, x_delta_new,
                                     kernel_id, w_sim, w_top, {emulator_sd}, {emulator_length_scale}, 1.0,
                                     no_discrepancy, no_discrepancy,
                                     append_row(prediction_normals_rng(normals_new, 1, P), rep_vector(0, P)))[1:P];
    }
    vector[P] f_link_new = link_from_standardised(likelihood_id, f_std_new, y_center, y_scale);
    tuple(vector[P], vector[P], vector[P], vector[P]) at_new = latent_prediction_quantities_rng(
      likelihood_id, f_link_new, h_new * beta, delta, x_delta, x_delta_new, kernel_id, delta_sd, delta_length_scale,
      normals_new, sd_obs, precision, trials_new, units, y_center, y_scale);
    f_new = at_new.1;
    delta_new = at_new.2;
    zeta_new = at_new.3;
    y_new = at_new.4;
  }
}
