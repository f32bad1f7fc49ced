/**
 * The user's simulator at the physical points, standardised like y, with
 * checks that name what to fix. Needs simulator(matrix, vector) defined
 * before this file is included.
 *
 * @param X inputs, one row per point, original units
 * @param theta calibration parameters, original units
 * @param y_center, y_scale the standardisation applied to y
 * @return (simulator(X, theta) - y_center) / y_scale
 */
vector standardized_simulator(matrix X, vector theta, real y_center, real y_scale) {
  vector[rows(X)] f = simulator(X, theta);
  if (rows(f) != rows(X)) {
    reject("simulator(X, theta) returned ", rows(f), " values for ", rows(X),
           " rows of X; it must return one value per row of X");
  }
  for (i in 1:rows(X)) {
    if (is_nan(f[i]) || is_inf(f[i])) {
      reject("simulator(X, theta) returned ", f[i], " at row ", i, " of X = ", X[i],
             " with theta = ", theta, "; make it finite over the whole theta box");
    }
  }
  return (f - y_center) / y_scale;
}
