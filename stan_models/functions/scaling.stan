/**
 * Calibration parameters on their original scale from the unit cube.
 *
 * @param theta_unit parameters in [0, 1]
 * @param lower_bound lower bounds, original units
 * @param upper_bound upper bounds, original units
 * @return parameters in original units
 */
vector theta_from_unit(vector theta_unit, vector lower_bound, vector upper_bound) {
  return lower_bound + (upper_bound - lower_bound) .* theta_unit;
}
