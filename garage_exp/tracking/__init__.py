"""MLflow: a job's run and the sweep's parent (runs), the local sqlite store (store), HTML pages (page)."""
