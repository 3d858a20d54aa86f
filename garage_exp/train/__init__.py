"""Training a detector on the project's own data (issue 22): `python -m garage_exp.train`.

Inputs are suites, `dataset=true` job outputs and YOLO data.yaml files (data: gathered, checked and split by
scenario), the base a `.pt`, a model YAML or a registered `models:/garage-detector/N` (base), and the training
is ultralytics' own trainer, tracked as one MLflow run and registered as `garage-detector` (fit).
"""
