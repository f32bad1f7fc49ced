// Data declarations (include inside a data block): the standard normals
// stancal gives for the draws of the Hilbert-space basis weights when it
// reruns generated quantities under PyStan, whose RNG is seeded with 0 on
// every call. Transformed data checks them with check_given_normals
// (given_normals.stan) against the number of weights drawn.
  int<lower=0> B_normals;               // the number of weights drawn = they use basis_normals, 0 = Stan's RNG
  vector[B_normals] basis_normals;      // standard normals for those draws
