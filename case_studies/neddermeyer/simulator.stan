/**
 * The scaled inner radius y = r / R1 of Neddermeyer's (1943) imploding
 * cylinder, as SEPIA's example integrates it (make_data.py: Euler steps of
 * 0.01 us from y = lam), from time 0 to at least ``latest`` (us).
 *
 * @param m the explosive-to-steel mass ratio
 * @param theta (yield stress GPa, HE energy MJ/kg)
 * @param latest the latest time asked for, us
 * @return y at times 0, 0.01, 0.02, ... us
 */
vector neddermeyer_path(real m, vector theta, real latest) {
  real R1 = 1.5 * 2.54;      // outer radius, cm
  real lam = 2.0 / 3;        // inner over outer radius
  real rho = 7.5;            // steel, g/cm^3
  real s = theta[1] * 1e10;  // dyn/cm^2
  real v0 = m * sqrt(2 * theta[2] * 1e10 / (1 + m));  // cm/s
  int steps = 2;
  while ((steps - 2) * 0.01 < latest) steps += 1;
  vector[steps] path;
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
  return path;
}

/**
 * Neddermeyer's implosion for method koh: the physics itself, no emulator.
 * Rows of X are (mass_ratio, time, angle): the explosive-to-steel mass
 * ratio, the time (us) and the angle (rad, unused: the implosion is round);
 * theta = (yield_stress, he_energy) in GPa and MJ/kg. Returns the inner
 * radius (cm), linear between Euler steps; the cylinder is integrated once
 * per distinct mass ratio among the rows.
 */
vector simulator(matrix X, vector theta) {
  int n = rows(X);
  vector[n] radius = rep_vector(0, n);  // every row is set below; stanc cannot tell
  array[n] int done = rep_array(0, n);
  for (first in 1:n) {
    if (done[first]) continue;
    real latest = 0;
    for (i in first:n) if (X[i, 1] == X[first, 1]) latest = fmax(latest, X[i, 2]);
    int steps = 2;  // as neddermeyer_path counts them
    while ((steps - 2) * 0.01 < latest) steps += 1;
    vector[steps] path = neddermeyer_path(X[first, 1], theta, latest);
    for (i in first:n) {
      if (X[i, 1] == X[first, 1]) {
        int k = 1;  // (k - 1) * 0.01 <= time < k * 0.01
        while (k * 0.01 <= X[i, 2] && k + 1 < steps) k += 1;
        real w = X[i, 2] / 0.01 - (k - 1);
        radius[i] = 1.5 * 2.54 * ((1 - w) * path[k] + w * path[k + 1]);
        done[i] = 1;
      }
    }
  }
  return radius;
}
