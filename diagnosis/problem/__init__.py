"""The diagnosis problem: what is compared (window features, motion regimes), the effect
parameters and their keys, the training / held-out layout of every residual, the structure
tests of a residual and the shrink of a gap."""
