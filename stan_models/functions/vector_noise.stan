/**
 * Each measured value's independent variance: its known noise, one noise
 * sd for all, or one per experiment (noise_mode 0, 1, 2).
 *
 * @param noise_mode 0 = known per value, 1 = one sd, 2 = one per experiment
 * @param known_noise_sd known noise sd of each value (noise_mode 0)
 * @param noise_sd observation noise sd, standardised units
 * @param experiment the experiment of each value
 * @return each value's independent variance, standardised units
 */
vector independent_variance(int noise_mode, vector known_noise_sd, array[] real noise_sd,
                            array[] int experiment) {
  if (noise_mode == 0) return square(known_noise_sd);
  if (noise_mode == 1) return rep_vector(square(noise_sd[1]), size(experiment));
  return square(to_vector(noise_sd)[experiment]);
}
