"""`python -m garage_exp.verify data=PATH detector=...`: score a detector on a labelled image set (COCO JSON or YOLO
data.yaml), log an MLflow run, write a report. Exit codes: 0 done, 2 bad input (one line, nothing written)."""

from garage_exp.verify.app import cli

if __name__ == "__main__":
    cli()
