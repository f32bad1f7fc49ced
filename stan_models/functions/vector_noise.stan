/**
 * Each measured value's independent variance: its known noise, one noise
 * sd for all, or one per experiment (noise_mode 0, 1, 2).
 */
vector independent_variance(int noise_mode, vector known_noise_sd, array[] real noise_sd,
                            array[] int experiment) {
  if (noise_mode == 0) return square(known_noise_sd);
  if (noise_mode == 1) return rep_vector(square(noise_sd[1]), size(experiment));
  return square(to_vector(noise_sd)[experiment]);
}
