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
