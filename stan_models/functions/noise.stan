/**
 * The measurement noise of the exact Gaussian programs (koh, koh_emulator,
 * modular; docs/noise.md). Row i's noise has the scale s_i, with
 *   s_i^2 = sigma[source_i]^2 + known_sd_i^2:
 * sigma is estimated, one per measurement source (noise_id 2) or one for all
 * rows, and known_sd is the row's stated measurement sd (0 where none is
 * given), added in quadrature: the stated error plus an estimated excess,
 * the "intrinsic scatter" of Hogg, Bovy & Lang (2010, section 7). Where the
 * stated sd is right, sigma goes to 0 and the fit is that of a known noise.
 *
 * Student-t noise (noise_id 3, Lange, Little & Taylor 1989) with nu degrees
 * of freedom and scale s_i is the scale mixture of normals
 *   eps_i | w_i ~ N(0, s_i^2 / w_i),  w_i ~ gamma(nu / 2, nu / 2)
 * (Geweke 1993). Where a GP is integrated out (a multivariate normal over the
 * points) the weights w are sampled with theta and the GP stays marginalised
 * given them, as Neal (1997) did for GP regression with t noise; without a
 * GP the t density is used as it is. A row whose weight is small is one the
 * fit discounts: an outlier (West 1984).
 * Heteroscedastic noise (noise_id 4) has an input-dependent sd,
 *   s_i = noise_sd * exp(g(u_i) - mean_k g(u_k)),  g ~ GP(0, SE kernel) over the noise inputs u,
 * so that noise_sd is the geometric mean of the sd over the K distinct settings u_k (uncentred, g's
 * own level traded with noise_sd along a ridge: on case_studies/hetero_noise the mean tree depth
 * fell from 6.6 to 5.0 with the centring; docs/noise.md),
 * the log sd a latent GP (Goldberg, Williams & Bishop 1998; Binois, Gramacy &
 * Ludkovski 2018) sampled with theta, as in the calibration of Sung, Barber &
 * Walker (2022) with replicated experiments (review section 8.1.2). g lives at
 * the distinct locations of the noise inputs only: replicates share its value,
 * and it is non-centred (its values are the GP's Cholesky factor times standard normals).
 * noise_id: 1 = iid, 2 = per_source, 3 = student_t, 4 = heteroscedastic (stancal.problem.codes.Noise).
 */

/**
 * Each row's noise variance s_i^2 under the normal model (Student-t: the
 * square of its scale).
 *
 * @param noise_sd estimated noise sd per source (one for all: size 1), standardised units
 * @param source each row's source, 1..size(noise_sd)
 * @param known_sd each row's stated measurement sd, standardised units (0 = none)
 * @return s_i^2, one per row
 */
vector noise_variance(array[] real noise_sd, array[] int source, vector known_sd) {
  return square(to_vector(noise_sd)[source]) + square(known_sd);
}

/**
 * Heteroscedastic noise: the log noise sd's GP g at the distinct locations of
 * the noise inputs, non-centred: g = chol(K) z, K the squared exponential
 * kernel (with the jitter of add_jitter), z standard normals. log(s_i / noise_sd) = g[loc_i] - mean(g).
 *
 * @param x_noise the distinct locations, scaled to [0, 1] (none: homoscedastic noise)
 * @param gp_sd the GP's marginal sd, in log sd units (size 1 where there are locations)
 * @param length_scale its length scales, one per noise input, fractions of the input's range
 * @param z standard normals, one per location
 * @return g at the locations (empty without locations)
 */
vector noise_log_scale_at(array[] vector x_noise, array[] real gp_sd, array[] real length_scale, vector z) {
  int n = size(x_noise);
  if (n == 0) return rep_vector(0, 0);
  return cholesky_decompose(add_jitter(ard_cov(x_noise, 1, gp_sd[1], length_scale), square(gp_sd[1]))) * z;
}

/**
 * Each row's noise variance: noise_variance's, or with heteroscedastic noise
 * s_i^2 = (noise_sd * exp(g[loc_i] - mean(g)))^2 + known_sd_i^2.
 *
 * @param noise_sd estimated noise sd per source (heteroscedastic: its geometric mean over the settings),
 *        standardised units
 * @param source each row's source, 1..size(noise_sd)
 * @param known_sd each row's stated measurement sd, standardised units (0 = none)
 * @param log_scale g at the distinct locations (noise_log_scale_at; empty: homoscedastic)
 * @param loc each row's location, 1..rows(log_scale) (empty: homoscedastic)
 * @return s_i^2, one per row
 */
vector row_noise_variance(array[] real noise_sd, array[] int source, vector known_sd, vector log_scale,
                          array[] int loc) {
  if (size(loc) == 0) return noise_variance(noise_sd, source, known_sd);
  return square(noise_sd[1] * exp(log_scale[loc] - mean(log_scale))) + square(known_sd);
}

/**
 * Prior of the log noise sd GP's length scales: lognormal with 95 % of its
 * mass between the noise inputs' mean spacing and their range (stancal sets
 * the two numbers from the data: docs/noise.md), so that the GP neither
 * wiggles between neighbouring locations nor is flat by construction.
 *
 * @param length_scale the length scales (empty: homoscedastic)
 * @param prior the lognormal's location and scale
 * @return its log prior density
 */
real noise_length_scale_lpdf(array[] real length_scale, vector prior) {
  return lognormal_lupdf(length_scale | prior[1], prior[2]);
}

/**
 * Prior of the log noise sd GP's marginal sd: half-normal(0, 1), median
 * 0.67: a typical curve spans about 4 sd = 2.7 in log sd over the inputs (a
 * change of about 15-fold), and 100-fold remains plausible (docs/noise.md).
 *
 * @param gp_sd the marginal sd (empty: homoscedastic)
 * @return its log prior density
 */
real noise_gp_sd_lpdf(array[] real gp_sd) {
  return normal_lupdf(gp_sd | 0, 1);
}

/**
 * Prior of the Student-t degrees of freedom: gamma(2, 0.1), mean 20, which
 * keeps both heavy tails and the near-normal limit plausible (Juarez & Steel
 * 2010; the Stan prior-choice recommendations).
 *
 * @param nu the degrees of freedom (an empty array: normal noise)
 * @return its log prior density
 */
real noise_dof_lpdf(array[] real nu) {
  return gamma_lupdf(nu | 2, 0.1);
}

/**
 * Prior of the scale-mixture weights: w_i ~ gamma(nu / 2, nu / 2), so that
 * the noise given nothing but nu is Student-t (Geweke 1993).
 *
 * @param weight one weight per row (an empty vector: no mixture)
 * @param nu the degrees of freedom (size 1 when there are weights)
 * @return their log prior density
 */
real noise_weight_lpdf(vector weight, array[] real nu) {
  if (rows(weight) == 0) return 0;
  return gamma_lupdf(weight | 0.5 * nu[1], 0.5 * nu[1]);
}

/**
 * The rows' noise variances given the mixture weights: s_i^2 / w_i (the
 * variances unchanged without weights). The diagonal a GP's covariance adds.
 *
 * @param variance s_i^2 per row (noise_variance)
 * @param weight the mixture weights (an empty vector: none)
 * @return each row's noise variance given its weight
 */
vector weighted_noise_variance(vector variance, vector weight) {
  if (rows(weight) == 0) return variance;
  return variance ./ weight;
}

/**
 * Log density of independent residuals (no GP), normal or Student-t.
 *
 * @param resid observed minus mean, one per row
 * @param variance s_i^2 per row (noise_variance)
 * @param nu the degrees of freedom (an empty array: normal)
 * @return log p(resid) (without constants where called by ~, as Stan's own densities)
 */
real independent_noise_lpdf(vector resid, vector variance, array[] real nu) {
  if (size(nu) == 0) return normal_lupdf(resid | 0, sqrt(variance));
  return student_t_lupdf(resid | nu[1], 0, sqrt(variance));
}

/**
 * Pointwise log density of independent residuals, normal or Student-t.
 *
 * @param resid observed minus mean, one per row
 * @param variance s_i^2 per row (noise_variance)
 * @param nu the degrees of freedom (an empty array: normal)
 * @return log p(resid_i), one per row
 */
vector noise_log_lik(vector resid, vector variance, array[] real nu) {
  int n = rows(resid);
  vector[n] out;
  for (i in 1:n) {
    out[i] = size(nu) == 0 ? normal_lpdf(resid[i] | 0, sqrt(variance[i]))
                           : student_t_lpdf(resid[i] | nu[1], 0, sqrt(variance[i]));
  }
  return out;
}

/**
 * Observations drawn about their means with the rows' noise: given the
 * mixture weights where they are sampled (each row keeps its weight, so that
 * the prior's draws of y follow the joint model, as simulation-based
 * calibration needs), else normal or Student-t.
 *
 * @param mean each row's mean
 * @param variance s_i^2 per row (noise_variance)
 * @param nu the degrees of freedom (an empty array: normal)
 * @param weight the sampled mixture weights (an empty vector: none)
 * @return one observation per row
 */
vector noise_rng(vector mean, vector variance, array[] real nu, vector weight) {
  if (rows(weight) > 0) return to_vector(normal_rng(mean, sqrt(weighted_noise_variance(variance, weight))));
  if (size(nu) == 0) return to_vector(normal_rng(mean, sqrt(variance)));
  return to_vector(student_t_rng(nu[1], mean, sqrt(variance)));
}

/**
 * Each row's weight in the fit: the sampled mixture weight, or without a GP
 * its mean given the residual, E(w_i | resid_i) = (nu + 1) / (nu + resid_i^2 / s_i^2)
 * (Lange, Little & Taylor 1989, eq. 5). Small: the fit treats the row as an outlier.
 *
 * @param resid observed minus mean, one per row
 * @param variance s_i^2 per row (noise_variance)
 * @param nu the degrees of freedom (an empty array: normal noise, no weights)
 * @param weight the sampled mixture weights (an empty vector: none)
 * @return one weight per row (none for normal noise)
 */
vector outlier_weight(vector resid, vector variance, array[] real nu, vector weight) {
  if (size(nu) == 0) return rep_vector(0, 0);
  if (rows(weight) > 0) return weight;
  return (nu[1] + 1) ./ (nu[1] + square(resid) ./ variance);
}
