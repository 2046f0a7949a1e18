"""Render farm: job manifests (``manifest``), the worker that renders their tasks (``worker``),
executors that run them locally or on Dask (``executors``) and exports for farm managers
(``flamenco``)."""
