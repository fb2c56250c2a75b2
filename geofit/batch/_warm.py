"""The Dask worker plugin that prepares every worker before its first target.

Kept apart from :mod:`geofit.batch._tasks` because it imports ``distributed`` (its base class),
which a task itself does not need.
"""
from __future__ import annotations

from distributed.diagnostics.plugin import WorkerPlugin

from ._tasks import warm_up


class WarmUp(WorkerPlugin):
    """Runs :func:`geofit.batch._tasks.warm_up` (thread limits, imports) on every worker of the
    cluster, present and future, once registered with ``client.register_plugin``.

    Registering it again (another task or thread count) replaces it, and its ``setup`` runs
    again on every worker. ``report`` holds the worker's :func:`warm_up` result.
    """

    name = "geofit-warm-up"
    idempotent = False

    def __init__(self, task: str, threads: int):
        self.task, self.threads = task, int(threads)
        self.report: dict = {}

    def setup(self, worker) -> None:
        self.report = warm_up(self.task, self.threads)
