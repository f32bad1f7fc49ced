// Data declarations (include inside a data block, not in functions): the
// standard normals stancal gives for the draws at the prediction points when
// it reruns generated quantities under PyStan, whose RNG is seeded with 0 on
// every call (see prediction_normals_rng in gp_conditional.stan).
// Transformed data checks them with check_given_normals (given_normals.stan).
  int<lower=0> P_normals;               // P = the draws at the prediction points use normals_new, 0 = Stan's RNG
  matrix[P_normals, 2] normals_new;     // standard normals for those draws; column 1: simulator (emulator), 2: discrepancy
