"""Offline batch reprocessing of many sessions on dask.distributed (``fielddiag reprocess``).

* :mod:`~fielddiag.batch.discover`: find sessions, pair before/after drives.
* :mod:`~fielddiag.batch.task`: the work of one pair, as a worker runs it.
* :mod:`~fielddiag.batch.runner`: the cluster (local or remote) and the scheduling.
* :mod:`~fielddiag.batch.store`: the SQLite catalog the dashboard reads.
* :mod:`~fielddiag.batch.reprocess`: plan, run and record a batch.
"""
