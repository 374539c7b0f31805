"""Decide the motion: block probability of a shield disk or a moving shield against the crossing
Gaussian, values and backup on the tree, the runtime view of the tree, the re-rooted choice.
Pure kernels over numpy arrays."""
