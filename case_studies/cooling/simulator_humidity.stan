// Newton cooling whose heat transfer rate depends on humidity (a decoy
// candidate: humidity plays no part in this case study's reality).
// X columns: t, T0, humidity (%). theta: k (1/min), gamma (per 50 % humidity).
vector simulator(matrix X, vector theta) {
  real ambient = 20;
  vector[rows(X)] rate = theta[1] * (1 + theta[2] * (X[:, 3] - 50) / 50);
  return ambient + (X[:, 2] - ambient) .* exp(-rate .* X[:, 1]);
}
