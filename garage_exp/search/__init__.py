"""The search for hard scenarios (issue 10): an Optuna study whose trials are garage_exp jobs.

`hydra/sweeper=search` (hydra_plugins/garage_search) asks Optuna for a trial, launches it as a job through
Hydra's launcher, and tells Optuna the trial's difficulty over its fairly visible frames. This package holds
what the sweeper uses: the search space from Hydra's override grammar (space), the study and its samplers
(study), the trial loop (loop), the analysis of a study (analysis, sensitivity) and graded suites (suite).
"""
