// Tip deflection (mm) of a polymer cantilever, length 0.5 m, second moment
// of area 2e-7 m^4, under a tip load F (N, column 1): w = F L^3 / (3 E I).
// theta[1] = E, Young's modulus (GPa). Temperature is not an input: how E
// depends on it is what the functional calibration finds.
vector simulator(matrix X, vector theta) {
  return 1e3 * X[:, 1] * 0.125 / (3 * theta[1] * 1e9 * 2e-7);
}
