"""What a person reads: the opening sentences, the verdict in words, the figures, and the
report folder (``report.html``, ``report.md``, ``diagnosis.json``)."""
