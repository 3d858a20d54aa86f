"""One job: check its inputs (preflight), run its MLflow run (job), render and score its frames (frames)."""
