"""The stages around the fit: transient events set aside, the calibrated baseline (clock,
frames, actuator convention), localisation of the gap, whole-run figures, training coverage,
the library's reach on the held-out data and discovery of an unexplained residual. Stages
see a robot only through the adapter contract and return values; none writes the verdict."""
