"""The problem as the user states it: physical data, simulator runs, the
observation model, mean terms, candidate effects and the config file."""
