// Newton's law of cooling: a cup at initial temperature T0 (deg C) in a room
// at 20 deg C, after t minutes, with heat transfer rate k (1/min).
// X columns: t, T0. theta: k.
vector simulator(matrix X, vector theta) {
  real ambient = 20;
  return ambient + (X[:, 2] - ambient) .* exp(-theta[1] * X[:, 1]);
}
