/**
 * Prior for ARD length scales of the discrepancy GP on unit-cube inputs.
 * Inverse gamma(3, 1) keeps 90 % of its mass between 0.16 and 1.2 of an
 * input's range and vanishes at 0, so the discrepancy cannot chase noise.
 *
 * @param length_scale one per input
 * @return log density
 */
real discrepancy_length_scale_lpdf(array[] real length_scale) {
  return inv_gamma_lpdf(length_scale | 3, 1);
}

/**
 * Prior for the relevance (inverse length scale, per input range) of each
 * covariate in the discrepancy GP: half-normal(0, 2). Unlike a length-scale
 * prior that vanishes at infinity, it keeps mass near relevance 0, where the
 * covariate is switched off, so a covariate that plays no part (a decoy) can
 * drop out of the discrepancy; a relevant one still reaches length scales
 * of a fifth of its range (relevance 5) at the prior's 99th percentile.
 *
 * @param relevance one per covariate
 * @return log density
 */
real covariate_relevance_lpdf(array[] real relevance) {
  return normal_lpdf(relevance | 0, 2);
}

/**
 * Prior for ARD length scales of the emulator GP over (x, theta) on the
 * unit cube. Inverse gamma(2, 1): 90 % between 0.21 and 2.8, because
 * simulators are often nearly linear in some inputs.
 *
 * @param length_scale one per input and calibration parameter
 * @return log density
 */
real emulator_length_scale_lpdf(array[] real length_scale) {
  return inv_gamma_lpdf(length_scale | 2, 1);
}

/**
 * Prior for ARD length scales of a functional theta's GP on unit-cube
 * inputs: inverse gamma(3, 1), as for the discrepancy, so theta(x) varies
 * smoothly over a fraction of an input's range at the shortest.
 *
 * @param length_scale one per functional input
 * @return log density
 */
real functional_length_scale_lpdf(vector length_scale) {
  return inv_gamma_lpdf(length_scale | 3, 1);
}

// The priors below drop constants as `~ normal(...)` would when called with
// `~` (their bodies use _lupdf), so the target is that of the former
// in-line statements.

/**
 * Prior for the observation noise sd, standardised units: half-normal(0, 1),
 * the standardised output's own scale (the parameter is declared <lower=0>).
 *
 * @param noise_sd the noise sd
 * @return log density
 */
real observation_noise_sd_lpdf(real noise_sd) {
  return normal_lupdf(noise_sd | 0, 1);
}

/**
 * Prior for the observation noise sds, standardised units: half-normal(0, 1)
 * each (an empty array where the likelihood has none).
 *
 * @param noise_sd the noise sds
 * @return log density
 */
real observation_noise_sd_lpdf(array[] real noise_sd) {
  return normal_lupdf(noise_sd | 0, 1);
}

/**
 * Prior for the discrepancy GP's marginal sd, model-scale units:
 * half-normal(0, 0.5), so the discrepancy is a fraction of the output's
 * spread (an empty array without a discrepancy).
 *
 * @param delta_sd the marginal sd
 * @return log density
 */
real discrepancy_sd_lpdf(array[] real delta_sd) {
  return normal_lupdf(delta_sd | 0, 0.5);
}

/**
 * Prior for the Kennedy-O'Hagan scale rho on the simulator: normal(1, 0.25)
 * on rho > 0, a simulator of about the right size (an empty array when rho
 * is fixed at 1).
 *
 * @param rho the scale
 * @return log density
 */
real koh_scale_lpdf(array[] real rho) {
  return normal_lupdf(rho | 1, 0.25);
}

/**
 * Prior for the negative binomial overdispersion 1 / sqrt(phi):
 * half-normal(0, 1), which keeps mass at 0, the Poisson limit (an empty array
 * for another likelihood).
 *
 * @param inv_sqrt_phi the overdispersion
 * @return log density
 */
real overdispersion_lpdf(array[] real inv_sqrt_phi) {
  return normal_lupdf(inv_sqrt_phi | 0, 1);
}

/**
 * Prior for the marginal sd of each functional theta's GP on the logit scale:
 * half-normal(0, 1.5).
 *
 * @param marginal_sd one per functional theta
 * @return log density
 */
real functional_sd_lpdf(vector marginal_sd) {
  return normal_lupdf(marginal_sd | 0, 1.5);
}

/**
 * Prior for the emulator GP's constant mean, standardised units: normal(0, 1).
 *
 * @param emulator_mean the mean
 * @return log density
 */
real emulator_mean_lpdf(real emulator_mean) {
  return normal_lupdf(emulator_mean | 0, 1);
}

/**
 * Prior for the emulator GPs' constant means, one per GP: normal(0, 1) each.
 *
 * @param emulator_mean the means
 * @return log density
 */
real emulator_mean_lpdf(vector emulator_mean) {
  return normal_lupdf(emulator_mean | 0, 1);
}

/**
 * Prior for the emulator GP's marginal sd, standardised units:
 * half-normal(0, 1).
 *
 * @param emulator_sd the marginal sd
 * @return log density
 */
real emulator_sd_lpdf(real emulator_sd) {
  return normal_lupdf(emulator_sd | 0, 1);
}

/**
 * Prior for the emulator GPs' marginal sds, one per GP: half-normal(0, 1) each.
 *
 * @param emulator_sd the marginal sds
 * @return log density
 */
real emulator_sd_lpdf(vector emulator_sd) {
  return normal_lupdf(emulator_sd | 0, 1);
}

/**
 * Prior for the emulator's nugget sd, standardised units: half-normal(0, 0.05),
 * since a simulator is (nearly) deterministic.
 *
 * @param emulator_nugget the nugget sd
 * @return log density
 */
real emulator_nugget_lpdf(real emulator_nugget) {
  return normal_lupdf(emulator_nugget | 0, 0.05);
}

/**
 * Prior for the emulator GPs' nugget sds, one per GP: half-normal(0, 0.05) each.
 *
 * @param emulator_nugget the nugget sds
 * @return log density
 */
real emulator_nugget_lpdf(vector emulator_nugget) {
  return normal_lupdf(emulator_nugget | 0, 0.05);
}
