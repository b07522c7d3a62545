"""The gap budget: the diagnosis's answer — how much of the held-out gap each effect
explains, chosen by one cross-validated rule, and what remains
(:mod:`~realitygap.diagnosis.budget.budget`)."""

from realitygap.diagnosis.budget.budget import SCHEMA, Budget, BudgetEntry, gap_budget, kind_of

__all__ = ["SCHEMA", "Budget", "BudgetEntry", "gap_budget", "kind_of"]
