// Tuo & Wu (2015) toy simulator (review section 6.2):
//   f(x, theta) = zeta(x) - sqrt(theta^2 - theta + 1) (sin(theta x) + cos(theta x)),
//   zeta(x) = exp(x / 10) sin(x). No theta makes f equal zeta.
// X columns: x. theta: theta.
vector simulator(matrix X, vector theta) {
  vector[rows(X)] x = X[:, 1];
  real t = theta[1];
  return exp(x / 10) .* sin(x) - sqrt(square(t) - t + 1) * (sin(t * x) + cos(t * x));
}
