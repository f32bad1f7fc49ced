// GP emulator of an expensive simulator from a table of runs: stage 1 of
// modular calibration (Bayarri et al. 2007b; Liu et al. 2009).
//   y_sim_j = f(x_sim_j, theta_sim_j) + nugget_j + intrinsic_j,
//   f ~ GP(emulator_mean, ARD kernel over (x, theta)).
// A stochastic simulator's runs carry their own known (stage-1 smoothed)
// intrinsic variance on the diagonal: stochastic kriging (Ankenman, Nelson &
// Staum 2010), f then emulates the simulator's mean; 0 for a deterministic one.
// Its replicates (runs at one (x, theta)) share one nugget: the emulator's
// misfit to the mean is one value per setting (functions/same_point.stan).
// Stancal fixes the hyperparameters at their posterior mode on the
// unconstrained scale (found by optimisation) for stage 2.
functions {
#include gp_kernels.stan
#include same_point.stan
#include loo.stan
#include priors.stan
}
data {
  int<lower=1> M;                       // number of simulator runs
  int<lower=1> D;                       // number of simulator inputs
  int<lower=1> Q;                       // number of calibration parameters
  array[M] vector[D] x_sim;             // simulator inputs of the runs, scaled to [0, 1]
  array[M] vector[Q] theta_sim;         // theta of the runs, scaled to [0, 1] within its bounds
  vector[M] y_sim;                      // simulator output of the runs, standardised
  vector<lower=0>[M] run_intrinsic_sd;  // stochastic simulator: each run's intrinsic sd, standardised (0 = deterministic)
  real<lower=0> y_scale;                // original-scale differences = y_scale * standardised ones
  int<lower=1, upper=2> kernel_id;      // 1 = squared exponential, 2 = Matern 5/2
  int<lower=0, upper=1> prior_only;     // 1 = ignore y_sim: draws from the prior
}
transformed data {
  array[M] vector[D + Q] xt_sim;
  for (j in 1:M) xt_sim[j] = append_row(x_sim[j], theta_sim[j]);
  // a stochastic simulator's replicates share one nugget draw; the identity otherwise
  matrix[M, M] replicated = replicated_runs(xt_sim, rep_array(1, M), run_intrinsic_sd);
}
parameters {
  real emulator_mean;
  real<lower=0> emulator_sd;
  array[D + Q] real<lower=0> emulator_length_scale;     // inputs first, then theta
  real<lower=0> emulator_nugget;
}
model {
  emulator_mean ~ emulator_mean();                   // normal(0, 1)
  emulator_sd ~ emulator_sd();                       // half-normal(0, 1)
  emulator_length_scale ~ emulator_length_scale();   // inverse gamma(2, 1)
  emulator_nugget ~ emulator_nugget();               // half-normal(0, 0.05)
  if (!prior_only) {
    matrix[M, M] K = emulator_run_cov(xt_sim, kernel_id, emulator_sd, emulator_length_scale, emulator_nugget,
                                      replicated, run_intrinsic_sd);
    y_sim ~ multi_normal_cholesky(rep_vector(emulator_mean, M), cholesky_decompose(K));
  }
}
generated quantities {
  vector[M] log_lik;       // log p(y_sim_j | other runs, hyperparameters), original units
  vector[M] loo_error;     // leave-one-out prediction error of each run, original units
  {
    matrix[M, M] K_inv = chol2inv(cholesky_decompose(
      emulator_run_cov(xt_sim, kernel_id, emulator_sd, emulator_length_scale, emulator_nugget, replicated,
                       run_intrinsic_sd)));
    vector[M] g = K_inv * (y_sim - emulator_mean);
    vector[M] c = diagonal(K_inv);
    log_lik = -0.5 * log(2 * pi()) + 0.5 * log(c) - 0.5 * square(g) ./ c - log(y_scale);
    loo_error = y_scale * g ./ c;
  }
}
