/**
 * Neddermeyer's (1943) implosion of a steel cylinder, as SEPIA's example
 * integrates it (make_data.py: Euler steps of 0.01 us from y = lam), for
 * method koh: the physics itself, no emulator. Rows of X are (mass_ratio,
 * time, angle): the explosive-to-steel mass ratio (one per experiment), the
 * time (us) and the angle (rad, unused: the implosion is round); theta =
 * (yield_stress, he_energy) in GPa and MJ/kg. Returns the inner radius (cm).
 * The cylinder is integrated once per call, to the latest time asked for.
 */
vector simulator(matrix X, vector theta) {
  real R1 = 1.5 * 2.54;      // outer radius, cm
  real lam = 2.0 / 3;        // inner over outer radius
  real rho = 7.5;            // steel, g/cm^3
  real step_us = 0.01;       // the example's Euler step
  real m = X[1, 1];          // the mass ratio is constant within an experiment
  real s = theta[1] * 1e10;  // dyn/cm^2
  real v0 = m * sqrt(2 * theta[2] * 1e10 / (1 + m));  // cm/s
  int steps = 2;
  while ((steps - 2) * step_us < max(X[:, 2])) steps += 1;
  vector[steps] path;        // y = r / R1 at times (i - 1) * step_us
  path[1] = lam;
  for (i in 2:steps) {
    real y = path[i - 1];
    if (y <= 0) {
      path[i] = 0;             // closed: stays closed
    } else {
      real y2 = square(y);
      real a = y2 + 1 - square(lam);
      real f = y2 / (1 - square(lam)) * log(a / y2);
      real g = (y2 * log(y2) - a * log(a) - square(lam) * log(square(lam))) / (1 - square(lam));
      real energy = square(v0) / 2 - s * g / (2 * rho);
      real speed = energy > 0 ? sqrt(2 / (square(R1) * f) * energy) : 0;
      path[i] = fmax(y - speed * 1e-8, 0);
    }
  }
  vector[rows(X)] radius;
  for (n in 1:rows(X)) {       // linear between the steps either side of each time
    int k = 1;
    while (k * step_us <= X[n, 2] && k + 1 < steps) k += 1;
    real w = X[n, 2] / step_us - (k - 1);
    radius[n] = R1 * ((1 - w) * path[k] + w * path[k + 1]);
  }
  return radius;
}
