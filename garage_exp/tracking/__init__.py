"""MLflow: a job's run and the sweep's parent (`runs`, the API the layers above use, and its parts: client,
experiments, provenance, jobrun, sweepfiles, ui), the local sqlite store (store), HTML pages (page)."""
