// Hagen-Poiseuille friction loss in a 10 mm pipe, in kPa.
// X columns: v (m/s), L (m). theta: mu (mPa s).
vector simulator(matrix X, vector theta) {
  real diameter = 0.01;
  return 32 * theta[1] * 1e-3 * X[:, 2] .* X[:, 1] / square(diameter) / 1000;
}
