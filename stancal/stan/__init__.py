"""Everything that touches Stan: the registry of programs, their source and
includes, their data, and the backends that compile and sample them."""
