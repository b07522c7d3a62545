"""Validation of the diagnosis on robots whose hidden effects are known: the blind suite."""
