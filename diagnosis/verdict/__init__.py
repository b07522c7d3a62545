"""The verdict: which effects explain the held-out gap, or why none does.

Its types (:mod:`~realitygap.diagnosis.verdict.types`: the frozen ``Verdict``, its kind,
confidence and notes), the held-out tests (:mod:`~realitygap.diagnosis.verdict.judge`), the
two-scale test (:mod:`~realitygap.diagnosis.verdict.scales`), identifiability advice
(:mod:`~realitygap.diagnosis.verdict.advice`), the rules
(:mod:`~realitygap.diagnosis.verdict.rules`) and the one writer of a ``Verdict``
(:mod:`~realitygap.diagnosis.verdict.conclude`). Each step returns a value; only
``conclude`` constructs the verdict."""
