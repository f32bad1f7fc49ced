/**
 * Observation models of the latent-GP programs (koh_latent*.stan): the
 * outputs need not be Gaussian (review section 8.1.4; Grosskopf et al. 2021)
 * and Gaussian outputs may be censored (section 8.1.5; Cao et al. 2018).
 * eta is the linear predictor on the model scale: the standardised output
 * for gaussian, log E[y] for poisson and negbinomial, logit P(success) for
 * binomial.
 * likelihood_id: 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 *   (mirrored in Python by stancal.models.Likelihood).
 * censoring: 0 = observed, 1 = left (y <= upper), 2 = right (y >= lower),
 *   3 = interval (lower <= y <= upper) (mirrored by stancal.models.Censoring).
 */

/**
 * Pointwise log-likelihood given the linear predictor.
 *
 * @param noise_sd gaussian noise sd on the standardised scale (else unused)
 * @param phi negative binomial precision, Var = mu + mu^2 / phi (else unused)
 * @param y_real gaussian: standardised output (unused where censored)
 * @param y_int counts or successes (unused for gaussian)
 * @param trials binomial trials (unused otherwise)
 * @param censoring censoring code and standardised bounds per point
 * @param lower_bound censoring code and standardised bounds per point
 * @param upper_bound censoring code and standardised bounds per point
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param eta linear predictor on the model scale
 * @return log p(y_i | eta_i), one per point
 */
vector observation_log_lik(int likelihood_id, vector eta, real noise_sd, real phi,
                           vector y_real, array[] int y_int, array[] int trials,
                           array[] int censoring, vector lower_bound, vector upper_bound) {
  int n = rows(eta);
  vector[n] out;
  for (i in 1:n) {
    if (likelihood_id == 1) {
      if (censoring[i] == 0) {
        out[i] = normal_lpdf(y_real[i] | eta[i], noise_sd);
      } else if (censoring[i] == 1) {
        out[i] = normal_lcdf(upper_bound[i] | eta[i], noise_sd);
      } else if (censoring[i] == 2) {
        out[i] = normal_lccdf(lower_bound[i] | eta[i], noise_sd);
      } else {
        out[i] = log_diff_exp(normal_lcdf(upper_bound[i] | eta[i], noise_sd),
                              normal_lcdf(lower_bound[i] | eta[i], noise_sd));
      }
    } else if (likelihood_id == 2) {
      out[i] = poisson_log_lpmf(y_int[i] | eta[i]);
    } else if (likelihood_id == 3) {
      out[i] = neg_binomial_2_log_lpmf(y_int[i] | eta[i], phi);
    } else {
      out[i] = binomial_logit_lpmf(y_int[i] | trials[i], eta[i]);
    }
  }
  return out;
}

/**
 * Replicated observations given the linear predictor; gaussian ones on the
 * standardised scale. The log mean is capped at 20 (5e8 counts) because
 * Stan's count RNGs refuse larger means, which only prior draws reach.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param eta linear predictor on the model scale
 * @param noise_sd observation noise sd, standardised units
 * @param phi negative binomial precision, Var = mu + mu^2 / phi (else unused)
 * @param trials binomial trials (unused otherwise)
 * @return one replicated observation per point (gaussian: standardised)
 */
vector observation_rng(int likelihood_id, vector eta, real noise_sd, real phi,
                       array[] int trials) {
  int n = rows(eta);
  vector[n] out;
  for (i in 1:n) {
    if (likelihood_id == 1) {
      out[i] = normal_rng(eta[i], noise_sd);
    } else if (likelihood_id == 2) {
      out[i] = poisson_log_rng(fmin(eta[i], 20));
    } else if (likelihood_id == 3) {
      out[i] = neg_binomial_2_log_rng(fmin(eta[i], 20), phi);
    } else {
      out[i] = binomial_rng(trials[i], inv_logit(eta[i]));
    }
  }
  return out;
}

/**
 * A cheap simulator's mean on the model scale: standardised like y for
 * gaussian, g(f) (log for counts, logit for binomial) otherwise, with a
 * check that names the point. The link scale is not standardised, so
 * y_center and y_scale are used for gaussian only.
 *
 * @param f simulator output on the response scale, original units
 * @param X the points, for the message
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return the simulator on the model scale, one per point
 */
vector simulator_model_scale(int likelihood_id, vector f, matrix X, real y_center, real y_scale) {
  if (likelihood_id == 1) return (f - y_center) / y_scale;
  for (i in 1:rows(f)) {
    if (likelihood_id <= 3 && !(f[i] > 0)) {
      reject("simulator(X, theta) returned the mean ", f[i], " at row ", i, " of X = ", X[i],
             "; a count likelihood has a log link, so the simulator must return a mean > 0 ",
             "over the whole theta box");
    }
    if (likelihood_id == 4 && !(f[i] > 0 && f[i] < 1)) {
      reject("simulator(X, theta) returned the success probability ", f[i], " at row ", i,
             " of X = ", X[i], "; a binomial likelihood has a logit link, so the simulator ",
             "must return a value strictly between 0 and 1 over the whole theta box");
    }
  }
  return likelihood_id == 4 ? logit(f) : log(f);
}

/**
 * From the standardised emulator scale to the model scale: unchanged for
 * gaussian (its model scale is standardised), link units otherwise.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param f_std the emulator's output, standardised like the runs
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return the emulator on the model scale
 */
vector link_from_standardised(int likelihood_id, vector f_std, real y_center, real y_scale) {
  return likelihood_id == 1 ? f_std : y_center + y_scale * f_std;
}

/**
 * The mean response in original units from the model scale.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param eta linear predictor on the model scale
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return the mean response in original units
 */
vector response_scale(int likelihood_id, vector eta, real y_center, real y_scale) {
  if (likelihood_id == 1) return y_center + y_scale * eta;
  if (likelihood_id == 4) return inv_logit(eta);
  return exp(eta);
}

/**
 * Original units per model-scale unit of the discrepancy: y_scale for
 * gaussian (standardised), 1 on a link scale.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return y_scale for gaussian, 1 otherwise
 */
real discrepancy_units(int likelihood_id, real y_scale) {
  return likelihood_id == 1 ? y_scale : 1.0;
}

/**
 * Pointwise log-likelihood in original units: the densities of exact
 * Gaussian rows were taken on the standardised scale (censored rows are
 * probabilities and need no change).
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param log_lik pointwise log-likelihood on the model scale
 * @param censoring 0 = observed, 1 = left, 2 = right, 3 = interval, per point
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return the pointwise log-likelihood in original units
 */
vector log_lik_original_units(int likelihood_id, vector log_lik, array[] int censoring,
                              real y_scale) {
  vector[rows(log_lik)] out = log_lik;
  if (likelihood_id == 1) {
    for (i in 1:rows(out)) {
      if (censoring[i] == 0) out[i] -= log(y_scale);
    }
  }
  return out;
}

/**
 * Observations drawn on the model scale, in original units.
 *
 * @param likelihood_id 1 = gaussian, 2 = poisson, 3 = negbinomial, 4 = binomial
 * @param y observations on the model scale (observation_rng)
 * @param y_center original-scale y = y_center + y_scale * y: the centre
 * @param y_scale original-scale y = y_center + y_scale * y: the scale
 * @return the observations in original units
 */
vector observations_original_units(int likelihood_id, vector y, real y_center, real y_scale) {
  return likelihood_id == 1 ? y_center + y_scale * y : y;
}
