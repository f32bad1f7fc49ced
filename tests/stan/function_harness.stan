// Exposes the shared functions to the tests (run with fixed_param).
functions {
// a simulator with known derivatives: f = exp(-theta_1 x_1) + theta_2 x_2^2
vector simulator(matrix X, vector theta) {
  return exp(-theta[1] * X[:, 1]) + theta[2] * square(X[:, 2]);
}
#include simulator_output.stan
#include gp_kernels.stan
#include gp_conditional.stan
#include koh_joint.stan
#include loo.stan
#include scaling.stan
#include restricted_gp.stan
#include latent_gp.stan
#include observation_model.stan
#include latent_loo.stan
#include functional_theta.stan
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
}
generated quantities {
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
    x2, append_theta(coordinate(x1, 1), [0.3]'), x1, 1, sd_, ls, 0.01, 1.3, {0.7}, {0.4, 0.6}, 0.2);
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
}
