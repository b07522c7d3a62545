"""Logs: the recorded episode (:class:`~realitygap.diagnosis.logs.log.Log`), its on-disk format,
the channels robots record, and the readers of the files robots write (``read.py``,
``importers/``). The lowest layer of the diagnosis: it knows a robot only through
:mod:`realitygap.robots`."""
