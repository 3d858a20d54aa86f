"""`python -m garage_exp.train data=[...] base=yolov8n.yaml epochs=10`: train a detector, track it in MLflow and
register it as `garage-detector`. Exit codes: 0 done, 2 bad input (one line, nothing written or registered)."""

from garage_exp.train.app import cli

if __name__ == "__main__":
    cli()
