"""Console entry points. They only parse arguments and wire library calls; the work is in the library."""
