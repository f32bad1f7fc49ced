// Concentration (mg/L) of a compound that decays at first order:
// c(t) = c0 exp(-k t), t in hours (column 1), c0 the dosed concentration
// (mg/L, column 2). theta[1] = k, the decay rate (1/h).
vector simulator(matrix X, vector theta) {
  return X[:, 2] .* exp(-theta[1] * X[:, 1]);
}
