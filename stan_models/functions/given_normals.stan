/**
 * Check the standard normals stancal may give for draws in generated
 * quantities (prediction_normals_data.stan, basis_normals_data.stan): none,
 * or exactly one per value drawn. Rejects the data otherwise.
 *
 * @param given the number given (P_normals or B_normals)
 * @param needed the number of values drawn with them (P, or the basis weights)
 */
void check_given_normals(int given, int needed) {
  if (given != 0 && given != needed) {
    reject("the given standard normals (P_normals or B_normals) must be 0 or ", needed, "; got ", given);
  }
}
