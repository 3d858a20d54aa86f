"""`python -m garage_exp.verify data=PATH`: a detector scored on labelled real images (docs/perception.md)."""
