"""Many scenes at once: a dataset folder (:mod:`~evpose.core.dataset.dataset`), the per-scene tasks run on
a Dask cluster (:mod:`~evpose.core.dataset.cluster`, :mod:`~evpose.core.dataset.batch`,
:mod:`~evpose.core.dataset.tasks`), the dataset export (:mod:`~evpose.core.dataset.export`) and the
triage report."""
