// The expensive cooling simulator, exactly (the reference the emulators are
// judged against): a cup at T0 (deg C) in a room at 20 deg C after t minutes,
// with convection at rate k (1/min) and a loss c (T - Ta)^2, c = 4e-4 per
// deg C per minute; the exact solution of dT/dt = -k (T - Ta) - c (T - Ta)^2.
// X columns: t, T0. theta: k.
vector simulator(matrix X, vector theta) {
  real ambient = 20;
  real c = 4e-4;
  vector[rows(X)] excess = X[:, 2] - ambient;
  vector[rows(X)] decay = exp(-theta[1] * X[:, 1]);
  return ambient + theta[1] * excess .* decay ./ (theta[1] + c * excess .* (1 - decay));
}
