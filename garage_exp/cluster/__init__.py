"""Beyond one machine: sweeps and searches on a Ray cluster (`hydra/launcher=ray`)."""
