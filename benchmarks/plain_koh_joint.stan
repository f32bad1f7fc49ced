// The baseline of benchmarks/ess_per_second.py: joint Kennedy-O'Hagan
// calibration written as a user would write it by hand in Stan, with no
// stancal machinery. One GP emulator over (x, theta) trained on the runs,
// a GP discrepancy over x, Gaussian noise, everything sampled jointly:
//   y_sim_j = f(x_sim_j, theta_sim_j),   y_i = f(x_i, theta) + delta(x_i) + eps_i.
// Inputs and theta on the unit cube, outputs standardised (by the caller).
data {
  int<lower=1> N;
  int<lower=1> M;
  int<lower=1> D;
  int<lower=1> Q;
  array[N] vector[D] x;
  vector[N] y;
  array[M] vector[D] x_sim;
  array[M] vector[Q] theta_sim;
  vector[M] y_sim;
}
transformed data {
  array[M] vector[D + Q] xt_sim;
  for (j in 1:M) xt_sim[j] = append_row(x_sim[j], theta_sim[j]);
  vector[M + N] z = append_row(y_sim, y);
}
parameters {
  vector<lower=0, upper=1>[Q] theta;
  real beta0;
  real<lower=0> sigma_f;
  array[D + Q] real<lower=0> ell_f;
  real<lower=0> sigma_d;
  array[D] real<lower=0> ell_d;
  real<lower=0> sigma_e;
}
model {
  array[N] vector[D + Q] xt_obs;
  for (i in 1:N) xt_obs[i] = append_row(x[i], theta);
  matrix[M + N, M + N] K;
  K[1:M, 1:M] = gp_exp_quad_cov(xt_sim, sigma_f, ell_f);
  K[1:M, (M + 1):(M + N)] = gp_exp_quad_cov(xt_sim, xt_obs, sigma_f, ell_f);
  K[(M + 1):(M + N), 1:M] = K[1:M, (M + 1):(M + N)]';
  K[(M + 1):(M + N), (M + 1):(M + N)] = gp_exp_quad_cov(xt_obs, sigma_f, ell_f)
                                        + gp_exp_quad_cov(x, sigma_d, ell_d);
  for (i in 1:M) K[i, i] += 1e-6;
  for (i in (M + 1):(M + N)) K[i, i] += square(sigma_e);

  beta0 ~ normal(0, 1);
  sigma_f ~ normal(0, 1);
  ell_f ~ inv_gamma(2, 1);
  sigma_d ~ normal(0, 0.5);
  ell_d ~ inv_gamma(3, 1);
  sigma_e ~ normal(0, 1);
  z ~ multi_normal_cholesky(rep_vector(beta0, M + N), cholesky_decompose(K));
}
