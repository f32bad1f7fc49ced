// Exposes the shared functions to the tests (run with fixed_param).
functions {
// a simulator with known derivatives: f = exp(-theta_1 x_1) + theta_2 x_2^2
vector simulator(matrix X, vector theta) {
  return exp(-theta[1] * X[:, 1]) + theta[2] * square(X[:, 2]);
}
#include simulator_output.stan
#include gp_kernels.stan
#include gp_conditional.stan
#include noise.stan
#include fidelity.stan
#include same_point.stan
#include koh_joint.stan
#include loo.stan
#include scaling.stan
#include restricted_gp.stan
#include latent_gp.stan
#include observation_model.stan
#include latent_loo.stan
#include functional_theta.stan
#include latent_koh.stan
#include priors.stan
#include hsgp.stan
#include chebyshev.stan
#include vector_noise.stan
#include vector_output.stan
#include vector_simulator.stan
#include given_normals.stan
/**
 * One coordinate of each point, as 1-vectors.
 *
 * @param x the points
 * @param k the coordinate
 * @return x[i][k] as a 1-vector per point
 */
array[] vector coordinate(array[] vector x, int k) {
  array[size(x)] vector[1] out;
  for (i in 1:size(x)) out[i] = x[i][k:k];
  return out;
}
}
data {
  int<lower=1> n1;
  int<lower=1> n2;
  array[n1] vector[2] x1;
  array[n2] vector[2] x2;
  real<lower=0> sd_;
  array[2] real<lower=0> ls;
  vector[n1] resid;
  vector[3] unit;
  vector[3] lo;
  vector[3] hi;
  matrix[n1, 2] A_restrict;
  real<lower=0> ridge;
  vector[4] eta;                        // linear predictor of four observations
  vector[4] y_real;
  array[4] int y_int;
  array[4] int trials;
  array[4] int censoring;
  vector[4] lower_bound;
  vector[4] upper_bound;
  matrix[3, 2] X_sim;                   // inputs of the simulator above
  vector[2] theta_sim;                  // its theta, inside [theta_lo, theta_hi]
  vector[2] theta_lo;
  vector[2] theta_hi;
  vector[n2] z_draw;                    // standard normals for a conditional draw
  int<lower=0> given_count;             // check_given_normals(given_count, needed_count)
  int<lower=0> needed_count;
  array[2] real<lower=0> source_sd;     // noise.stan: an estimated noise sd per source
  array[n1] int<lower=1, upper=2> source;  // each point's source
  vector<lower=0>[n1] known_sd;         // each point's known noise sd
  vector<lower=0>[n1] mix_weight;       // Student-t scale-mixture weights
  array[1] real<lower=0> nu;            // Student-t degrees of freedom
}
transformed data {
  check_given_normals(given_count, needed_count);
  array[3, 2] int hs_index = {{1, 1}, {2, 1}, {1, 3}};  // Hilbert-space basis functions
  vector[2] hs_boundary = [1.5, 1.8]';
}
generated quantities {
  // noise.stan
  vector[n1] noise_var = noise_variance(source_sd, source, known_sd);
  vector[n1] noise_var_weighted = weighted_noise_variance(noise_var, mix_weight);
  vector[n1] noise_ll_normal = noise_log_lik(resid, noise_var, rep_array(0.0, 0));
  vector[n1] noise_ll_t = noise_log_lik(resid, noise_var, nu);
  real noise_total_normal = independent_noise_lpdf(resid | noise_var, rep_array(0.0, 0));
  real noise_total_t = independent_noise_lpdf(resid | noise_var, nu);
  vector[n1] noise_row_weight = outlier_weight(resid, noise_var, nu, rep_vector(0, 0));
  vector[n1] noise_row_weight_sampled = outlier_weight(resid, noise_var, nu, mix_weight);
  real noise_weight_density = noise_weight_lpdf(mix_weight | nu);
  real noise_dof_density = noise_dof_lpdf(nu);
  matrix[n1, n2] se_cross = ard_cross_cov(x1, x2, 1, sd_, ls);
  matrix[n1, n2] m52_cross = ard_cross_cov(x1, x2, 2, sd_, ls);
  matrix[n1, n1] se_sym = ard_cov(x1, 1, sd_, ls);
  matrix[n1, n1] m52_sym = ard_cov(x1, 2, sd_, ls);
  // points x1 that share the second coordinate of x1[1] (a theta), against x2:
  // the x factor times theta_factor, as modular.stan computes it
  matrix[n1, n2] se_cross_shared_theta = diag_post_multiply(
    gp_exp_quad_cov(coordinate(x1, 1), coordinate(x2, 1), sd_, ls[1:1]),
    theta_factor(x1[1][2:2], coordinate(x2, 2), ls[2:2]));
  tuple(vector[n1], vector[n1]) loo_both = mvn_loo(resid, cholesky_decompose(add_diag(se_sym, 0.1)));
  vector[n1] loo = loo_both.1;
  vector[n1] loo_mean = loo_both.2;
  vector[n2] conditional_draw = gp_conditional_draw(resid, cholesky_decompose(add_diag(se_sym, 0.1)),
                                                    se_cross', ard_cov(x2, 1, sd_, ls), z_draw);
  vector[n2] given_normals = prediction_normals_rng(to_matrix(z_draw, n2, 1), 1, n2);
  vector[0] no_normals = std_normals_rng(0);  // an empty draw, as for a problem with no functional theta
  // runs with a repeated point and a vanishing nugget: factorisable only with the jitter
  matrix[n2 + 1, n2 + 1] repeated_runs_cholesky = cholesky_decompose(
    emulator_run_cov(append_array(x2, x2[1:1]), 1, sd_, ls, 0));
  matrix[3, 2] dfdtheta = simulator_theta_derivatives(X_sim, theta_sim, theta_lo, theta_hi, 0, 1);
  matrix[3, 2] dfdtheta_at_bound = simulator_theta_derivatives(X_sim, theta_lo, theta_lo, theta_hi, 0, 1);
  vector[n2] conditional_mean = gp_conditional_mean(resid, cholesky_decompose(add_diag(se_sym, 0.1)),
                                                    se_cross');
  vector[3] theta = theta_from_unit(unit, lo, hi);
  // restricted GPs with the nodes U = x1: orthogonal to two functionals, and scaled
  matrix[n1, n1] orthogonal_cov = se_sym - crossprod(restriction_factor(
    se_sym, A_restrict, restriction_cholesky(se_sym, A_restrict, 0)));
  matrix[n1, n1] scaled_cov = se_sym - crossprod(restriction_factor(
    se_sym, identity_matrix(n1), restriction_cholesky(se_sym, identity_matrix(n1), ridge)));
  // joint KOH covariance: runs x2 (as (x, theta) with 1 input + 1 theta), physical x1 inputs
  // observation models: gaussian with each censoring code, then the count likelihoods
  vector[4] gaussian_censored = observation_log_lik(1, eta, 0.7, 1, y_real, y_int, trials, censoring,
                                                    lower_bound, upper_bound);
  vector[4] poisson = observation_log_lik(2, eta, 1, 1, y_real, y_int, trials, censoring,
                                          lower_bound, upper_bound);
  vector[4] negbinomial = observation_log_lik(3, eta, 1, 3.5, y_real, y_int, trials, censoring,
                                              lower_bound, upper_bound);
  vector[4] binomial = observation_log_lik(4, eta, 1, 1, y_real, y_int, trials, censoring,
                                           lower_bound, upper_bound);
  vector[4] response = response_scale(4, eta, 0, 1);
  // the latent emulator at x1 (with theta 0.3) given runs x2 and outputs resid[1:4], z = 0: its mean
  vector[n1] emulator_mean_at = emulator_latent(
    cholesky_decompose(add_diag(ard_cov(x2, 1, sd_, ls), 0.01)), x2, resid[1:n2],
    append_theta(coordinate(x1, 1), [0.3]'), 1, 0.2, sd_, ls, rep_vector(0, n1));
  // theta rows: theta 1 scalar, theta 2 functional with logit values at two points
  matrix[2, 2] theta_rows = theta_rows_original(theta_unit_rows([0.25, 0.5]', {0, 1}, [[0.0], [2.0]]),
                                                [0, 10]', [1, 20]');
  matrix[n2 + n1, n2 + n1] joint = koh_joint_cov(
    x2, rep_matrix(1, n2, 1), append_theta(coordinate(x1, 1), [0.3]'), [1], x1, 1, {sd_}, {ls},
    rep_vector(0.01, n2), 1.3, {0.7}, {0.4, 0.6}, noise_var);
  // two fidelities (level 2 = 1.7 level 1 + its own GP): the top level at x1 against runs at x2 of
  // levels 1, 2, 1, 2
  matrix[2, 2] fidelity_w = fidelity_weights([1.7]');
  // three levels, scales linear in two inputs (x2's points), each point at its own level
  matrix[n2, 3] fidelity_point_w = fidelity_point_weights([1.7, 0.6]', [[0.5, -0.4], [-0.3, 0.9]], x2, {1, 2, 3, 3});
  row_vector[3] fidelity_widest_w = fidelity_widest(fidelity_point_w, {sd_, 0.5, 0.2});
  matrix[n1, n2] fidelity_cross = fidelity_cross_cov(x1, rep_matrix(fidelity_w[2, :], n1), x2,
                                                     fidelity_w[{1, 2, 1, 2}, :], 1, {sd_, 0.5},
                                                     {ls, {0.2, 0.9}});
  // latent LOO of the four observations with delta = resid[1:4] at x2 (nugget 0.01), for each
  // observation model (row k: likelihood_id k), y_center 0.2 and y_scale 1.5
  matrix[4, 4] latent_loo_lik;
  matrix[4, 4] latent_loo_mean;
  vector[20] quadrature_nodes;
  vector[20] quadrature_weights;
  {
    tuple(vector[20], vector[20]) rule = normal_quadrature(20);
    quadrature_nodes = rule.1;
    quadrature_weights = rule.2;
    matrix[4, 4] L_latent = cholesky_decompose(add_diag(ard_cov(x2, 1, sd_, ls), 0.01));
    for (k in 1:4) {
      tuple(vector[4], vector[4]) out = latent_loo(k, eta, resid[1:4], L_latent, 0.7, 3.5, y_real, y_int,
                                                   trials, censoring, lower_bound, upper_bound, 0.2, 1.5,
                                                   rule);
      latent_loo_lik[k] = out.1';
      latent_loo_mean[k] = out.2';
    }
  }
  // the discrepancy's covariances at x1 and x2, orthogonal to two functionals at the nodes U = x1
  matrix[n1, n1] restricted_K;
  matrix[n2, n1] restricted_K_cross;
  matrix[n2, n2] restricted_K_new;
  {
    tuple(matrix[n1, n1], matrix[n2, n1], matrix[n2, n2]) K_all
      = restricted_gp_cov(x1, x2, x1, A_restrict, 1, sd_, ls, 0);
    restricted_K = K_all.1;
    restricted_K_cross = K_all.2;
    restricted_K_new = K_all.3;
  }
  // unrestricted: A without rows
  matrix[n2, n1] unrestricted_K_cross = restricted_gp_cov(x1, x2, x1[1:0], rep_matrix(0, 0, 2), 1, sd_, ls, 0).2;
  // every prior of priors.stan at given values (full densities: called as _lpdf)
  vector[16] priors = [discrepancy_length_scale_lpdf({0.3, 0.7}), covariate_relevance_lpdf({0.5, 2.0}),
                       emulator_length_scale_lpdf({0.3, 0.7}), functional_length_scale_lpdf([0.3, 0.7]'),
                       observation_noise_sd_lpdf(0.4), observation_noise_sd_lpdf({0.4, 0.9}),
                       discrepancy_sd_lpdf({0.3}), koh_scale_lpdf({1.1}),
                       overdispersion_lpdf({0.6}),
                       functional_sd_lpdf([0.8, 2.0]'), emulator_mean_lpdf(0.3), emulator_mean_lpdf([0.3, -1.2]'),
                       emulator_sd_lpdf(0.5), emulator_sd_lpdf([0.5, 1.5]'), emulator_nugget_lpdf(0.01),
                       emulator_nugget_lpdf([0.01, 0.1]')]';
  // Hilbert-space GP: basis at x1, weight sds (length scales capped at 0.5), marginal density, weights
  matrix[n1, 3] hs_basis = hsgp_basis(x1, hs_index, hs_boundary);
  vector[3] hs_sd_se = hsgp_weight_sd(hs_index, hs_boundary, 1, sd_, ls, {0.5, 0.5});
  vector[3] hs_sd_m52 = hsgp_weight_sd(hs_index, hs_boundary, 2, sd_, ls, {0.5, 0.5});
  real hs_marginal = hsgp_marginal_lpdf(resid | hs_basis', crossprod(hs_basis), hs_sd_se, 0.3);
  real hs_marginal_sums = hsgp_marginal_from_sums(dot_self(resid), hs_basis' * resid, n1, crossprod(hs_basis),
                                                  hs_sd_m52, 0.3);
  vector[3] hs_weights = hsgp_weights(resid, hs_basis', crossprod(hs_basis), hs_sd_se, 0.3, [0.1, -0.4, 0.7]');
  // Chebyshev tensor basis: degree 2 in theta 1, 1 in theta 2
  vector[6] chebyshev = chebyshev_tensor_basis([0.3, 0.8]', {2, 1});
  // vector outputs: independent variances per noise mode, for experiments {1, 2, 1}
  vector[3] variance_known = independent_variance(0, [0.1, 0.2, 0.3]', {0.5, 0.7}, {1, 2, 1});
  vector[3] variance_one = independent_variance(1, [0.1, 0.2, 0.3]', {0.5}, {1, 2, 1});
  vector[3] variance_per_experiment = independent_variance(2, [0.1, 0.2, 0.3]', {0.5, 0.7}, {1, 2, 1});
  // the simulator above per experiment: theta 1 shared, theta 2 each experiment's own
  vector[3] experiment_f = experiment_simulator(X_sim, {1, 2, 1}, theta_sim[1:1], {[0.5]', [2.0]'}, 0.2, 1.5);
  // weight GPs: one component's weights at x2 given runs x1 (alpha = resid) and variance runs x1, with
  // a nugget sd 0.3 shared by x2's points 1 and 3 (as if identical)
  matrix[n2, n2] same_point = [[1, 0, 1, 0], [0, 1, 0, 0], [1, 0, 1, 0], [0, 0, 0, 1]];
  vector[n2] component_mean;
  matrix[n2, n2] component_cov;
  {
    tuple(vector[n2], matrix[n2, n2]) w = component_weights(x2, x1, resid, x1,
                                                            cholesky_decompose(add_diag(se_sym, 0.1)), 0.2, sd_, ls,
                                                            0.3, same_point);
    component_mean = w.1;
    component_cov = w.2;
  }
  // two components' run factors with runs x1 and weights A_restrict
  array[2] matrix[n1, n1] factors_L;
  matrix[n1, 2] factors_alpha;
  {
    tuple(array[2] matrix[n1, n1], matrix[n1, 2]) f = weight_gp_factors(
      x1, A_restrict, [0.1, -0.2]', [sd_, 0.9]', {ls, {0.5, 0.6}}, [0.05, 0.1]');
    factors_L = f.1;
    factors_alpha = f.2;
  }
  // four experiments at x2's first coordinate with shared theta 0.3, two components
  matrix[n2, 2] experiment_means;
  array[2] matrix[n2, n2] experiment_covs;
  {
    array[n2] vector[0] none;
    matrix[n1, n1] L_var = cholesky_decompose(add_diag(se_sym, 0.1));
    tuple(matrix[n2, 2], array[2] matrix[n2, n2]) e = experiment_weights(
      coordinate(x2, 1), [0.3]', none, x1, A_restrict, x1, {L_var, L_var}, [0.2, -0.1]', [sd_, 0.9]',
      {ls, {0.5, 0.6}}, [0.05, 0.1]', same_point);
    experiment_means = e.1;
    experiment_covs = e.2;
  }
  matrix[4, 3] signal = signal_cov({1, 2, 1, 2}, [[1, 0.5], [0.2, -1], [0.3, 0.3], [-0.7, 2]], x2,
                                   {2, 1, 1}, [[0.4, 1], [1, 0], [-0.5, 0.5]], x1[1:3],
                                   {[[1, 0.3], [0.3, 2]], [[0.5, -0.1], [-0.1, 0.8]]}, {0.7}, {0.4, 0.6});
  // latent programs' shared pieces
  vector[4] observation_parameters = [observation_sd(1, {0.7}), observation_sd(3, {0.7}),
                                      negbinomial_precision(3, {0.5}), negbinomial_precision(1, {0.5})]';
  // functional theta 2 at three distinct points (x1[1:3]'s first coordinate), theta 1 scalar
  real functional_prior_centred = functional_theta_prior_lpdf(
    [[0.2], [-0.5], [1.0]] | [[9.0], [9.0], [9.0]], 1, [0.25, 0.5]', {0, 1}, coordinate(x1[1:3], 1), 1,
    [0.9]', {[0.4]'});
  real functional_prior_noncentred = functional_theta_prior_lpdf(
    [[0.2], [-0.5], [1.0]] | [[0.3], [-1.1], [0.6]], 0, [0.25, 0.5]', {0, 1}, coordinate(x1[1:3], 1), 1,
    [0.9]', {[0.4]'});
  // the discrepancy's latent GP at x2, centred (the values resid[1:4]) or non-centred (normals z_draw)
  vector[n2] latent_values_centred = latent_gp_values(resid[1:4], 1, x2, 1, sd_, ls);
  vector[n2] latent_values_noncentred = latent_gp_values(z_draw, 0, x2, 1, sd_, ls);
  real latent_prior_centred = latent_gp_prior_lpdf(resid[1:4] | 1, x2, 1, sd_, ls);
  real latent_prior_noncentred = latent_gp_prior_lpdf(z_draw | 0, x2, 1, sd_, ls);
  matrix[n2, 1] functional_grid;
  matrix[2, 2] functional_new;
  {
    tuple(matrix[n2, 1], matrix[2, 2]) q = functional_theta_quantities_rng(
      [0.25, 0.5]', {0, 1}, [[0.2], [-0.5], [1.0]], coordinate(x1[1:3], 1), coordinate(x2, 1),
      coordinate(x2[1:2], 1), 1, [0.9]', {[0.4]'}, [0, 10]', [1, 20]', [[0, 0, 0.3], [0, 0, -0.8]]);
    functional_grid = q.1;
    functional_new = q.2;
  }
  // latent_point_quantities_rng's deterministic parts: the latent LOO with delta's prior at x2
  // (latent_gp_cholesky: the jitter, no nugget), gaussian and poisson
  matrix[2, 4] point_loo_lik;
  matrix[2, 4] point_loo_mean;
  {
    tuple(vector[20], vector[20]) rule = normal_quadrature(20);
    for (k in 1:2) {
      tuple(vector[4], vector[4], vector[4]) out = latent_point_quantities_rng(
        k, eta, resid[1:4], x2, 1, {sd_}, ls, 0.7, 3.5, y_real, y_int, trials, censoring, lower_bound,
        upper_bound, 0.2, 1.5, rule);
      point_loo_lik[k] = out.1';
      point_loo_mean[k] = out.2';
    }
  }
}
