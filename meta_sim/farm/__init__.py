"""Render farm: job manifests (``manifest``), executors that run them locally or on Dask
(``executors``), exports for farm managers (``flamenco``) and the farm benchmark (``bench``)."""
