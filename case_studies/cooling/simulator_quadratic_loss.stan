// Cooling with convection and a quadratic loss (evaporation, radiation):
//   dT/dt = -k (T - Ta) - c (T - Ta)^2, solved exactly (a Bernoulli equation).
// X columns: t, T0. theta: k (1/min), c (1/(deg C min)).
vector simulator(matrix X, vector theta) {
  real ambient = 20;
  real k = theta[1];
  real c = theta[2];
  vector[rows(X)] excess = X[:, 2] - ambient;
  vector[rows(X)] decay = exp(-k * X[:, 1]);
  return ambient + k * excess .* decay ./ (k + c * excess .* (1 - decay));
}
