/**
 * The user's vector simulator at every measured value, standardised like y.
 * Each row of X is (inputs..., output index...) of one value; theta passed
 * to simulator() is the shared theta followed by the value's experiment's
 * own parameters, so with per-experiment parameters the simulator is called
 * once per experiment. Needs standardized_simulator (simulator_output.stan).
 *
 * @param X simulator rows, original units
 * @param experiment each row's experiment
 * @param theta shared parameters, original units
 * @param theta_experiment per experiment, its own parameters (size 0 each: none)
 * @param y_center the standardisation applied to y
 * @param y_scale the standardisation applied to y
 * @return (simulator(X, theta) - y_center) / y_scale
 */
vector experiment_simulator(matrix X, array[] int experiment, vector theta, array[] vector theta_experiment,
                            real y_center, real y_scale) {
  int n = rows(X);
  if (n == 0) return rep_vector(0, 0);
  if (rows(theta_experiment[1]) == 0) return standardized_simulator(X, theta, y_center, y_scale);
  vector[n] f = rep_vector(0, n);  // every row belongs to an experiment
  array[n] int rows_of = rep_array(1, n);  // the first k entries are experiment e's rows
  for (e in 1:size(theta_experiment)) {
    int k = 0;
    for (i in 1:n) {
      if (experiment[i] == e) {
        k += 1;
        rows_of[k] = i;
      }
    }
    if (k > 0) {
      f[rows_of[1:k]] = standardized_simulator(X[rows_of[1:k]], append_row(theta, theta_experiment[e]),
                                                y_center, y_scale);
    }
  }
  return f;
}

