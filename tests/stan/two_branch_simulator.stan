// f(x, theta) = g(theta) x with g = theta^2 for theta >= 0 and 4 theta^2 below:
// the data pin g(theta) = c, which two theta give. Under a uniform prior their
// posterior masses are in the ratio |dtheta/dc| = 1 / (2 sqrt(c)) : 1 / (4 sqrt(c)),
// exactly 2 : 1 for every c, so the positive mode holds 2/3 of the mass.
vector simulator(matrix X, vector theta) {
  real g = theta[1] >= 0 ? square(theta[1]) : 4 * square(theta[1]);
  return g * X[:, 1];
}
