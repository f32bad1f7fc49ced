// Data declarations (include inside a data block, after F): as
// prediction_normals_data.stan, for the latent programs, whose functional
// theta need a column each at the prediction points.
// Transformed data checks them with check_given_normals (given_normals.stan).
  int<lower=0> P_normals;               // P = the draws at the prediction points use normals_new, 0 = Stan's RNG
  matrix[P_normals, 2 + F] normals_new; // standard normals for those draws; column 1: simulator (emulator),
                                        // 2: discrepancy, 2 + k: the k-th functional theta
